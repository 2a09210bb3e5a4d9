"""The session's numpy and OpenBLAS code paths (tests/numeric_paths.py)."""

from __future__ import annotations

import os

import pytest

from tests import numeric_paths
from tests.numeric_paths import has_avx512, pin_numeric_paths

_VARIABLES = ("NPY_DISABLE_CPU_FEATURES", "OPENBLAS_CORETYPE")


@pytest.mark.skipif(not has_avx512(), reason="this host has no AVX-512: nothing is pinned")
def test_an_avx512_host_runs_the_tests_on_numpys_avx2_loops_and_openblas_haswell() -> None:
    from numpy._core._multiarray_umath import __cpu_features__

    assert os.environ["OPENBLAS_CORETYPE"] == "Haswell"
    disabled = os.environ["NPY_DISABLE_CPU_FEATURES"].split()
    assert disabled and all(not __cpu_features__[name] for name in disabled), disabled


def test_without_avx512_nothing_is_pinned(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(numeric_paths, "has_avx512", lambda: False)
    for name in _VARIABLES:
        monkeypatch.delenv(name, raising=False)
    pin_numeric_paths()
    assert not any(name in os.environ for name in _VARIABLES)


def test_variables_set_already_are_kept_and_a_late_pin_is_refused(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Set already (by the user, or inherited by a worker process): left as they are, though
    numpy is loaded. Not set, with numpy loaded: the pin could not apply, so it says so."""
    monkeypatch.setattr(numeric_paths, "has_avx512", lambda: True)
    monkeypatch.setenv("NPY_DISABLE_CPU_FEATURES", "")
    monkeypatch.setenv("OPENBLAS_CORETYPE", "SkylakeX")
    pin_numeric_paths()
    assert os.environ["NPY_DISABLE_CPU_FEATURES"] == ""
    assert os.environ["OPENBLAS_CORETYPE"] == "SkylakeX"
    monkeypatch.delenv("OPENBLAS_CORETYPE")
    with pytest.raises(RuntimeError, match="numpy was imported before"):
        pin_numeric_paths()  # numpy is loaded in this process
