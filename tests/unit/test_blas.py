"""BLAS pinned to one thread (skelfuse/blas.py): the libraries loaded now and those loaded later."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from skelfuse.blas import BLAS_THREAD_VARIABLES, pin_blas_threads


def _blas() -> list[dict[str, object]]:
    return [info for info in threadpool_info() if info.get("user_api") == "blas"]


def test_pin_leaves_every_loaded_blas_library_at_one_thread(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import numpy  # noqa: F401  (its OpenBLAS is the one fusion uses)

    if not _blas():
        pytest.skip("no BLAS library that threadpoolctl can control is loaded here")
    for name in BLAS_THREAD_VARIABLES:  # monkeypatch puts the process environment back after
        monkeypatch.delenv(name, raising=False)
    # The limiter records every library's thread count and restores it on exit, so the rest of
    # the test session keeps its own BLAS threads.
    with threadpool_limits(limits=None):
        pinned = pin_blas_threads()
        after = _blas()
    assert pinned, "the pin found no BLAS library"
    assert {str(info["filepath"]) for info in pinned} == {str(info["filepath"]) for info in after}
    assert [info["num_threads"] for info in after] == [1] * len(after), after
    for name in BLAS_THREAD_VARIABLES:
        assert os.environ[name] == "1"


def test_a_blas_library_loaded_after_the_pin_also_has_one_thread() -> None:
    """SciPy loads its own OpenBLAS on first use (calibration): the pin must reach it too."""
    pytest.importorskip("scipy")
    code = (
        "import json; from skelfuse.blas import pin_blas_threads; pin_blas_threads(); "
        "import scipy.linalg; from threadpoolctl import threadpool_info; "
        "print(json.dumps([[i['filepath'], i['num_threads']] for i in threadpool_info() "
        "if i['user_api'] == 'blas']))"
    )
    env = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARIABLES}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env,
        timeout=60,
    )  # fmt: skip
    libraries = json.loads(out.stdout)
    assert any("scipy" in path for path, _ in libraries), libraries
    assert [threads for _, threads in libraries] == [1] * len(libraries), libraries
