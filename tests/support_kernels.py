"""The compiled fusion kernels in tests: numba required where the kernels are tested.

:func:`require_numba` skips a test without numba, and fails it under CI (env ``CI``), where the
dev extra installs numba so the kernels must be tested. The ``numba_kernels`` fixture
(tests/conftest.py) uses it.
"""

from __future__ import annotations

import os

import pytest

from skelfuse.fusion.kernels_jit import numba_module


def require_numba() -> None:
    """Return when numba is installed; else skip the calling test (fail it under CI).

    Raises:
        pytest.fail.Exception: under CI without numba.
        pytest.skip.Exception: elsewhere without numba.
    """
    if numba_module() is None:
        if os.environ.get("CI"):
            pytest.fail("CI installs the dev extra, which has numba: the kernels must be tested")
        pytest.skip("numba is not installed (pip install -e .[fast])")
