"""Small helpers shared by tests (not fixtures)."""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Callable
from typing import NoReturn

import numpy as np
import numpy.typing as npt
import pytest

from skelfuse.fusion.kernels_jit import numba_module
from tests.support_blender import blender_executable


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def wait_until(predicate: Callable[[], object], timeout_s: float, interval_s: float = 0.05) -> bool:
    """Poll ``predicate`` until it is truthy (exceptions count as not yet) or time runs out."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if predicate():
                return True
        except Exception:
            pass
        time.sleep(interval_s)
    return False


def unavailable(reason: str, ci_hint: str) -> NoReturn:
    """Skip the calling test for want of a tool or data set; under CI (env ``CI``), which must
    provide it, fail it with ``ci_hint`` instead.

    Raises:
        pytest.skip.Exception, pytest.fail.Exception: always.
    """
    if os.environ.get("CI"):
        pytest.fail(f"{reason}: {ci_hint}", pytrace=False)
    pytest.skip(reason)


def require_blender() -> str:
    """Debian's ``blender`` executable, or :func:`unavailable` (skip; fail under CI)."""
    blender = blender_executable()
    if blender is None:
        unavailable(
            "Blender not found (/usr/bin/blender or `blender` on PATH)",
            "CI must install Debian's `blender` package (scripts/test.sh does)",
        )
    return blender


def require_numba() -> None:
    """Return when numba is installed, else :func:`unavailable` (skip; fail under CI, where the
    dev extra installs numba so the compiled kernels must be tested)."""
    if numba_module() is None:
        unavailable(
            "numba is not installed (pip install -e .[fast])",
            "CI installs the dev extra, which has numba: the kernels must be tested",
        )


def mpjpe(estimate: npt.ArrayLike, truth: npt.ArrayLike) -> tuple[float, int]:
    """Mean per-joint position error over the joints the estimate has (metres), and how many.

    Args:
        estimate, truth: (..., 25, 3) positions in the same frame; NaN in ``estimate`` means the
            joint was not reported and is left out (the count tells how many were scored).
    """
    est = np.asarray(estimate, dtype=np.float64).reshape(-1, 25, 3)
    ref = np.asarray(truth, dtype=np.float64).reshape(-1, 25, 3)
    err = np.linalg.norm(est - ref, axis=-1)
    present = np.isfinite(err)
    if not present.any():
        return float("nan"), 0
    return float(err[present].mean()), int(present.sum())
