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
IntArray = npt.NDArray[np.intp]

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


def project_bone_lengths(
    joints: FloatArray,
    reference: FloatArray,
    move: FloatArray,
    iterations: int,
    tables: tuple[IntArray, IntArray, IntArray, IntArray, IntArray, IntArray],
) -> FloatArray:
    """The compiled :func:`skelfuse.fusion.bones.project_bone_lengths` (same bits).

    Args:
        joints: (..., 25, 3) metres, NaN where unknown; reference: (..., 24) metres (NaN: leave
            that bone); move: (..., 25) mobilities, floored at 1e-6; iterations: passes;
            tables: :data:`skelfuse.fusion.bones.BONE_TABLES` (the skeleton's index tables).

    Returns:
        (..., 25, 3) float64.
    """
    from skelfuse.fusion import kernels_bones  # imports numba: only when used

    shape = joints.shape
    flat = plain(joints.reshape(-1, 25, 3))
    ref = plain(reference.reshape(-1, reference.shape[-1]))
    if move.shape != shape[:-1]:
        move = np.broadcast_to(move, shape[:-1])
    mobility = plain(move.reshape(-1, 25))
    out = np.empty_like(flat)
    grouped, parents, children, order, parent_of, bone_to = (plain(t, np.intp) for t in tables)
    kernels_bones.project_loop(
        flat,
        ref,
        mobility,
        int(iterations),
        grouped,
        parents,
        children,
        order,
        parent_of,
        bone_to,
        out,
    )
    result: FloatArray = out.reshape(shape)
    return result


def warm_up() -> float:
    """Compile (or load from numba's cache) every kernel now; returns the seconds it took
    (0.0 when the kernels are off). Call at start, off any latency-bound loop."""
    if not enabled():
        return 0.0
    start = time.perf_counter()
    from skelfuse.fusion import anatomy, labels, mirror, unbiased_facing, walking

    anatomy.warm_up()  # the mirror, labels and facing stages
    mirror.warm_up()
    labels.warm_up()
    unbiased_facing.warm_up()
    walking.warm_up()
    views = np.zeros((2, 25, 3))
    index = np.zeros(25, dtype=np.intp)  # the index tables' types, any content
    tables = (index, index, index, index, index, np.full(25, -1, dtype=np.intp))
    project_bone_lengths(views, np.ones((2, 24)), np.ones((2, 25)), 1, tables)
    from skelfuse.fusion import confidence, view_factors, weigh, weighted

    weighted.warm_up()
    confidence.warm_up()
    view_factors.warm_up()
    weigh.warm_up()
    # The bone observation's medians and the Kalman correction: they run once warmed.
    from skelfuse.fusion import (
        kernels_filter,
        kernels_lerp,
        kernels_median,
        kernels_motion,
        kernels_observe,
        kernels_replay,
        kernels_tracks,
        kernels_trunks,
    )

    kernels_observe.warm_up()  # callers check warmed() (and enabled())
    kernels_filter.warm_up()
    kernels_median.warm_up()
    kernels_trunks.warm_up()
    kernels_tracks.warm_up()
    kernels_motion.warm_up()
    kernels_lerp.warm_up()
    kernels_replay.warm_up()
    return time.perf_counter() - start
