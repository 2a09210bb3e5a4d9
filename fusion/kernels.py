"""Compiled kernels for the fusion step's hottest stages, with numpy as the reference.

The fusion step is many small numpy operations, each costing a microsecond or more of call
overhead on arrays of a few dozen rows. Where that overhead dominates, a loop compiled with
numba does the same arithmetic in one call. numba is optional (the ``fast`` extra): without it,
or with ``SKELFUSE_KERNELS=numpy`` in the environment, every stage runs its numpy version, which
stays the reference: each kernel computes the same IEEE operations in the same order and is
tested to give the same bits (tests/unit/test_kernels.py), so the fused output does not depend
on which path ran (tests/unit/test_golden_replay.py passes on both).

Kernels are compiled on first use, or ahead with :func:`warm_up` (the server and the replay call
it at start, so no frame waits for a compilation); ``cache=True`` keeps the machine code in
numba's cache (``__pycache__`` beside the module, or ``NUMBA_CACHE_DIR``) for the next process.

Modes (``SKELFUSE_KERNELS``): ``auto`` (default: numba when it imports), ``numba`` (the same,
named), ``numpy`` (never compile).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kernels_jit import numba_module, plain

FloatArray = npt.NDArray[np.float64]

ENV: Final = "SKELFUSE_KERNELS"
MODES: Final = ("auto", "numba", "numpy")

# Per thread: the fusion step forces its mode for its own duration, and a live server fuses in
# its own thread; one process-wide value would let overlapping steps restore each other's mode
# (left set for good) and let one thread's step change another's kernels.
_state = threading.local()


def mode() -> str:
    """The kernel mode: the one :func:`forced` set, else ``SKELFUSE_KERNELS`` (``auto``).

    Raises:
        ValueError: when ``SKELFUSE_KERNELS`` is not one of :data:`MODES`.
    """
    chosen: str | None = getattr(_state, "mode", None)
    if chosen is None:  # (once per kernel call: kept cheap)
        raw = os.environ.get(ENV)
        chosen = raw.strip().lower() or "auto" if raw else "auto"
    if chosen not in MODES:
        raise ValueError(f"{ENV} must be one of {', '.join(MODES)}, got {chosen!r}")
    return str(chosen)


def enabled() -> bool:
    """Whether the compiled kernels run (numba importable and the mode allows it)."""
    pinned: bool | None = getattr(_state, "enabled", None)  # inside :func:`forced`
    if pinned is not None:  # (asked ~20 times a step: 0.1 µs instead of 0.6–1.2)
        return pinned
    return mode() != "numpy" and numba_module() is not None


@contextmanager
def forced(chosen: str) -> Iterator[None]:
    """Run the block with the kernel mode ``chosen`` (tests, benches), whatever the environment,
    in this thread only.

    Raises:
        ValueError: when ``chosen`` is not one of :data:`MODES`.
    """
    if chosen not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {chosen!r}")
    saved: tuple[str | None, bool | None] = (
        getattr(_state, "mode", None),
        getattr(_state, "enabled", None),
    )
    _state.mode = chosen
    _state.enabled = chosen != "numpy" and numba_module() is not None
    try:
        yield
    finally:
        _state.mode, _state.enabled = saved


def rom_factors_and_forward(
    views: FloatArray, scale_deg: float, low: FloatArray, high: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The compiled :func:`skelfuse.fusion.anatomy.rom_factors_and_forward` (same bits).

    Args:
        views: (M, 25, 3) float64 joints, metres, world frame, NaN where unknown.
        scale_deg: degrees outside the range for a factor of 1/e.
        low, high: (13,) the angle limits, degrees, in the angle table's column order.

    Returns:
        factors (M, 25), forward (M, 3), as the numpy version.
    """
    joints = plain(views)
    factors = np.ones(joints.shape[:2])
    forward = np.empty((joints.shape[0], 3))
    from skelfuse.fusion.kernels_rom import rom_loop  # imports numba: only when used

    rom_loop(joints, float(scale_deg), plain(low), plain(high), factors, forward)
    return factors, forward


def weighted_mean(joints: FloatArray, weights: FloatArray) -> FloatArray:
    """The compiled :func:`skelfuse.fusion.weighted.weighted_mean` (same bits).

    Args:
        joints: (P, S, J, 3) positions, NaN where a view has none; weights: (P, S, J).

    Returns:
        (P, J, 3) float64, NaN where no view has a position with a positive weight.
    """
    from skelfuse.fusion import kernels_weighted  # imports numba: only when used

    points = plain(joints)
    out = np.empty((points.shape[0], points.shape[2], 3))
    kernels_weighted.weighted_loop(points, plain(weights), out)
    return out


def warm_up() -> float:
    """Compile (or load from numba's cache) every kernel now; returns the seconds it took
    (0.0 when the kernels are off). Call at start, off any latency-bound loop."""
    if not enabled():
        return 0.0
    start = time.perf_counter()
    views = np.zeros((2, 25, 3))
    limits = np.zeros(13)
    rom_factors_and_forward(views, 15.0, limits, limits)
    from skelfuse.fusion import (
        alignment_replay,
        bone_fit,
        bone_window,
        bones,
        filters_ca,
        measured_motion,
        trunks,
        world_views,
    )

    bone_fit.warm_up()
    bones.warm_up()
    bone_window.warm_up()
    trunks.warm_up()
    measured_motion.warm_up()
    world_views.warm_up()
    alignment_replay.warm_up()
    filters_ca.warm_up()
    weighted_mean(views[None], np.ones((1, 2, 25)))
    from skelfuse.fusion import kernels_stages  # the mirror and confidence stages' kernels

    kernels_stages.warm_up()
    from skelfuse.fusion import (
        kernels_label_stage,
        kernels_weigh,
    )

    kernels_weigh.warm_up()
    kernels_label_stage.warm_up()
    return time.perf_counter() - start
