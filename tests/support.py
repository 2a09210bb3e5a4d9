"""Small helpers shared by tests (not fixtures)."""

from __future__ import annotations

import os
import random
import socket
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import numpy.typing as npt
import pytest

from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.protocol.skeleton import JointId as J
from tests.support_blender import blender_executable


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now, below the kernel's ephemeral range.

    A server's port in the ephemeral range can be taken while the server is down: a client that
    keeps reconnecting to it (a ZeroMQ agent) may get that very port as its own local port and
    connect to itself (TCP simultaneous open), and the restarted server then cannot bind."""
    low = _ephemeral_low()
    for _ in range(200):
        port = random.randrange(max(1024, low - 12000), low)
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    raise RuntimeError(f"no free port below {low} on 127.0.0.1")


def _ephemeral_low() -> int:
    """The first port of the kernel's ephemeral range (Linux; 32768 where it cannot be read)."""
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768


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


def random_views(seed: int) -> npt.NDArray[np.float64]:
    """(M, 25, 3) views: simulated poses with noise, unknown joints, missing trunk parts, and
    random points (angles far outside every range, degenerate frames)."""
    rng = np.random.default_rng(seed)
    performer = ProceduralPerformer(3)
    poses = np.concatenate([performer.joints_at(t) for t in rng.uniform(0, 60, 12)])
    poses = poses + rng.normal(0.0, 0.05, poses.shape)
    noisy = poses + rng.normal(0.0, 0.3, poses.shape)
    unknown = noisy.copy()
    unknown[rng.random(unknown.shape[:2]) < 0.15] = np.nan
    trunk = poses[:8].copy()
    trunk[0:2, [J.HIP_LEFT, J.SHOULDER_RIGHT]] = np.nan  # the hips and the shoulders cut
    trunk[2:4, J.HIP_RIGHT, 1] = np.nan  # one hip known, the shoulders whole
    trunk[4:6, J.SPINE_SHOULDER] = np.nan  # no up axis
    trunk[6, J.HIP_LEFT] = trunk[6, J.HIP_RIGHT]  # a zero-length lateral vector
    random = rng.normal(0.0, 1.0, (20, 25, 3))
    coincident = np.zeros((2, 25, 3))
    return np.concatenate([poses, noisy, unknown, trunk, random, coincident])


def same_bits(a: npt.NDArray[Any], b: npt.NDArray[Any]) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()
