"""The session's numpy and OpenBLAS code paths (tests/numeric_paths.py)."""

from __future__ import annotations

import os

import pytest

from tests.numeric_paths import has_avx512


@pytest.mark.skipif(not has_avx512(), reason="this host has no AVX-512: nothing is pinned")
def test_an_avx512_host_runs_the_tests_on_numpys_avx2_loops_and_openblas_haswell() -> None:
    from numpy._core._multiarray_umath import __cpu_features__

    assert os.environ["OPENBLAS_CORETYPE"] == "Haswell"
    disabled = os.environ["NPY_DISABLE_CPU_FEATURES"].split()
    assert disabled and all(not __cpu_features__[name] for name in disabled), disabled
