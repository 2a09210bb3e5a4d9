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
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kernels_jit import numba_module

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

ENV: Final = "SKELFUSE_KERNELS"
MODES: Final = ("auto", "numba", "numpy")

_state: dict[str, str | None] = {"mode": None}


def mode() -> str:
    """The kernel mode: the one :func:`forced` set, else ``SKELFUSE_KERNELS`` (``auto``).

    Raises:
        ValueError: when ``SKELFUSE_KERNELS`` is not one of :data:`MODES`.
    """
    chosen = _state["mode"] or os.environ.get(ENV, "auto").strip().lower() or "auto"
    if chosen not in MODES:
        raise ValueError(f"{ENV} must be one of {', '.join(MODES)}, got {chosen!r}")
    return str(chosen)


def enabled() -> bool:
    """Whether the compiled kernels run (numba importable and the mode allows it)."""
    return mode() != "numpy" and numba_module() is not None


@contextmanager
def forced(chosen: str) -> Iterator[None]:
    """Run the block with the kernel mode ``chosen`` (tests, benches), whatever the environment.

    Raises:
        ValueError: when ``chosen`` is not one of :data:`MODES`.
    """
    if chosen not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {chosen!r}")
    saved = _state["mode"]
    _state["mode"] = chosen
    try:
        yield
    finally:
        _state["mode"] = saved


def _plain(array: npt.ArrayLike, dtype: type = np.float64) -> Any:
    """``array`` as a writable C-contiguous array of ``dtype`` (copied only when it is not):
    every call then has the argument types the warm-up compiled for, so no frame waits for a
    second compilation (a read-only or strided array is another numba signature)."""
    if (
        isinstance(array, np.ndarray)
        and array.dtype == dtype
        and array.flags.c_contiguous
        and array.flags.writeable
    ):  # the usual case, without np.require's cost (several µs a call)
        return array
    return np.require(array, dtype=dtype, requirements=("C", "W"))


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
    joints = _plain(views)
    factors = np.ones(joints.shape[:2])
    forward = np.empty((joints.shape[0], 3))
    from skelfuse.fusion.kernels_rom import rom_loop  # imports numba: only when used

    rom_loop(joints, float(scale_deg), _plain(low), _plain(high), factors, forward)
    return factors, forward


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
    flat = _plain(joints.reshape(-1, 25, 3))
    ref = _plain(reference.reshape(-1, reference.shape[-1]))
    mobility = _plain(np.broadcast_to(move, shape[:-1]).reshape(-1, 25))
    out = np.empty_like(flat)
    grouped, parents, children, order, parent_of, bone_to = (_plain(t, np.intp) for t in tables)
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


def weighted_mean(joints: FloatArray, weights: FloatArray) -> FloatArray:
    """The compiled :func:`skelfuse.fusion.weighted.weighted_mean` (same bits).

    Args:
        joints: (P, S, J, 3) positions, NaN where a view has none; weights: (P, S, J).

    Returns:
        (P, J, 3) float64, NaN where no view has a position with a positive weight.
    """
    from skelfuse.fusion import kernels_weighted  # imports numba: only when used

    points = _plain(joints)
    out = np.empty((points.shape[0], points.shape[2], 3))
    kernels_weighted.weighted_loop(points, _plain(weights), out)
    return out


def mirror_scores(
    views: FloatArray,
    sensor_positions: FloatArray,
    starts: IntArray,
    facings: FloatArray,
    references: FloatArray,
    anatomy_factors: FloatArray | None,
    previous: IntArray | None,
    terms: tuple[float, float, float, float, float],
    pairs: tuple[IntArray, IntArray],
    lateral: tuple[IntArray, IntArray],
    screen: tuple[int, float],
) -> npt.NDArray[np.bool_]:
    """The compiled scoring of :func:`skelfuse.fusion.mirror.choose_labellings` for persons
    whose facing is known (the same choices, from the same bits of every term).

    Args:
        views: (N, 25, 3) metres, world; sensor_positions: (N, 3); starts: (P + 1,) each
            person's first view, then N; facings: (P, 3) each person's facing (finite);
            references: (P, 25, 3) each person's last skeleton; anatomy_factors: (N, 2, 25)
            range-of-motion factors as reported and swapped, or None (no anatomy term);
            previous: (N,) last decisions (1, 0, −1 unknown) or None; terms: the track,
            geometry and anatomy weights, the swap prior and the hysteresis (metres);
            pairs: each pair's (first, second) views, person by person in ``PAIRS`` order;
            lateral: the lateral joints and where each one's other side is among them;
            screen: the view count from which labellings are screened, and the margin.

    Returns:
        (N,) bool, True where a view is mirrored.
    """
    from skelfuse.fusion import kernels_mirror  # imports numba: only when used

    points = _plain(views)
    total = points.shape[0]
    index = _plain(starts, np.intp)
    person_of = np.repeat(np.arange(len(index) - 1), np.diff(index))
    pair = np.empty((len(pairs[0]), 2, 2))
    to_ref = np.empty((total, 2))
    kernels_mirror.lateral_loop(
        points,
        _plain(lateral[0], np.intp),
        _plain(lateral[1], np.intp),
        _plain(pairs[0], np.intp),
        _plain(pairs[1], np.intp),
        _plain(references[person_of]),
        np.ones(total, dtype=np.bool_),
        pair,
        to_ref,
    )
    track, geometry, anatomy, prior, hysteresis = terms
    weights = np.array(
        [track, geometry, anatomy if anatomy_factors is not None else 0.0, prior, hysteresis,
         0.0 if previous is None else 1.0]
    )  # fmt: skip
    mirrored = np.zeros(total, dtype=np.bool_)
    kernels_mirror.score_loop(
        points,
        _plain(sensor_positions),
        index,
        _plain(facings),
        pair,
        to_ref,
        _plain(np.ones((total, 2, 1)) if anatomy_factors is None else anatomy_factors),
        _plain(np.full(total, -1) if previous is None else previous, np.intp),
        weights,
        int(screen[0]),
        float(screen[1]),
        mirrored,
    )
    return mirrored


def unbiased_facings(
    origins: FloatArray,
    sensor_positions: FloatArray,
    forward: FloatArray,
    mirrored: npt.NDArray[np.bool_],
    starts: IntArray,
    lean: float,
) -> FloatArray:
    """The compiled :func:`skelfuse.fusion.labels.unbiased_facings` (same bits), each view's own
    facing taken from the forward axis of its chosen labelling.

    Args:
        origins: (N, 3) each view's SpineBase, metres, world; sensor_positions: (N, 3);
        forward: (N, 2, 3) each view's forward axis as reported and swapped; mirrored: (N,)
        the labelling chosen; starts: (P + 1,) each person's first view, then N; lean: the
        share of its yaw a sensor turns a body towards itself, in [0, 1).

    Returns:
        (P, 3) horizontal unit vectors, NaN rows where unknown.
    """
    from skelfuse.fusion import kernels_facing  # imports numba: only when used

    out = np.empty((len(starts) - 1, 3))
    kernels_facing.unbiased_loop(
        _plain(origins),
        _plain(sensor_positions),
        _plain(forward),
        _plain(mirrored, np.bool_),
        _plain(starts, np.intp),
        float(lean),
        out,
    )
    return out


def facing_directions(skeletons: FloatArray) -> FloatArray:
    """The compiled :func:`skelfuse.fusion.anatomy.facing_directions` (same bits).

    Args:
        skeletons: (P, 25, 3) joints, metres, world frame (+Y up), NaN where unknown.

    Returns:
        (P, 3) horizontal unit vectors, NaN rows where unknown.
    """
    from skelfuse.fusion import kernels_facing  # imports numba: only when used

    out = np.empty((skeletons.shape[0], 3))
    kernels_facing.facing_loop(_plain(skeletons), out)
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
    index = np.zeros(25, dtype=np.intp)  # the index tables' types, any content
    tables = (index, index, index, index, index, np.full(25, -1, dtype=np.intp))
    project_bone_lengths(views, np.ones((2, 24)), np.ones((2, 25)), 1, tables)
    weighted_mean(views[None], np.ones((1, 2, 25)))
    pairs = (np.zeros(1, dtype=np.intp), np.ones(1, dtype=np.intp))
    lateral = (np.arange(20, dtype=np.intp), np.arange(20, dtype=np.intp))
    for anatomy in (None, np.ones((2, 2, 25))):
        mirror_scores(
            views, np.ones((2, 3)), np.array([0, 2]), np.ones((1, 3)), views[:1], anatomy,
            np.zeros(2, dtype=np.intp), (1.0, 0.1, 0.1, 0.01, 0.05), pairs, lateral, (6, 1e-9),
        )  # fmt: skip
    facing_directions(views)
    unbiased_facings(
        views[:, 0], np.ones((2, 3)), np.ones((2, 2, 3)), np.zeros(2, bool), np.array([0, 2]), 0.5
    )
    return time.perf_counter() - start
