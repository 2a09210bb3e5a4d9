"""bench/live/outputs.py runs (one second instead of sixty) and reports no frame lost."""

from __future__ import annotations

import pytest

pytest.importorskip("pylsl", reason="pylsl is not installed (pip install 'skelfuse[lsl]')")


def test_the_outputs_bench_loses_nothing_in_a_second() -> None:
    from bench.live.outputs import run

    report = run(1.0, 30.0)
    assert report["frames"] == 30
    for name in ("osc", "vmc", "lsl"):
        figures = report[name]
        assert isinstance(figures, dict)
        assert (figures["sent"], figures["dropped"], figures["lost"]) == (30, 0, 0), name
    for name in ("osc", "vmc"):
        assert 0 < report[name]["largest_datagram"] <= 1472  # type: ignore[index]
