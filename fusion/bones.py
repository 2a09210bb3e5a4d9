"""Bone lengths: each person's reference lengths (set by hand or estimated online) and the fit
that gives a fused skeleton those lengths.

Shapes: 25 joints, 24 bones in :data:`skelfuse.protocol.skeleton.BONES` order; metres.
"""

from __future__ import annotations

from typing import Final, Literal

import numpy as np
import numpy.typing as npt

from skelfuse.fusion import kernels, kernels_observe
from skelfuse.fusion.anatomy import CHAIN_LEVELS, CHAIN_ORDER
from skelfuse.fusion.bone_window import SampleWindow, nanmedian_last
from skelfuse.protocol.skeleton import BONE_MIRROR_PERMUTATION, BONES, PARENTS, TrackingState

FloatArray = npt.NDArray[np.float64]
BONE_COUNT: Final = len(BONES)
_BONE_PARENT: Final = np.array([parent for parent, _ in BONES])
_BONE_CHILD: Final = np.array([child for _, child in BONES])
_BONE_MIRROR: Final = np.array(BONE_MIRROR_PERMUTATION)
_BONE_ENDS: Final = (_BONE_PARENT, _BONE_CHILD)
_TRACKED: Final = int(TrackingState.TRACKED)
BoneFit = Literal["projection", "chain"]
GOOD_VIEW_COS: Final = 0.5
"""A view feeds the online bone-length estimate only if the person faces it within 60°."""


def enforce_bone_lengths(joints: npt.ArrayLike, reference: npt.ArrayLike) -> FloatArray:
    """Give a skeleton the reference bone lengths, keeping every bone's direction.

    Walks outward from SpineBase: each child is put at ``parent' + unit(child − parent)·l_ref``
    where ``parent'`` is the already-corrected parent. A bone whose reference is unknown (NaN)
    keeps its measured offset; NaN joints stay NaN.

    Args:
        joints: (25, 3) metres; reference: (24,) metres in :data:`BONES` order. Or several
            skeletons at once: (..., 25, 3) and (..., 24).

    Returns:
        (25, 3) float64 (or (..., 25, 3)).
    """
    original = np.asarray(joints, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    offsets = np.take(original, _BONE_CHILD, axis=-2) - np.take(original, _BONE_PARENT, axis=-2)
    # np.vecdot is the dot product np.linalg.norm uses on one vector (the same bits).
    norms = np.sqrt(np.vecdot(offsets, offsets))  # (..., 24)
    scale = np.isfinite(ref) & np.isfinite(norms) & (norms > 1e-9)
    factors = np.divide(ref, norms, out=np.ones_like(norms), where=scale)
    # SpineBase, then each bone's offset from its parent to its child, in BONES order.
    sources = np.concatenate(
        [
            original[..., _ROOT : _ROOT + 1, :],
            np.where(scale[..., None], offsets * factors[..., None], offsets),
        ],
        axis=-2,
    )
    # Every joint at once: its root-to-joint path's running sum, SpineBase then each bone's
    # offset in turn, which is the sum the walk below makes, in the same order (the same bits).
    # It holds wherever every parent is known: so wherever the result is all finite.
    summed = np.cumsum(np.take(sources, _PATH_SOURCES, axis=-2), axis=-2)
    result: FloatArray = np.take(
        summed.reshape(*summed.shape[:-3], _PATHS.size, 3), _PATH_INDEX, axis=-2
    )
    if np.isfinite(result).all():
        return result
    out = original.copy()
    # Outward one depth level at a time; a joint whose parent is missing keeps its measurement.
    for children, parents in CHAIN_LEVELS:
        hung = np.isfinite(out[..., parents, :]).all(axis=-1, keepdims=True)
        out[..., children, :] = np.where(
            hung,
            out[..., parents, :] + sources[..., _SOURCE_OF[children], :],
            out[..., children, :],
        )
    return out


def _chain_paths() -> tuple[int, npt.NDArray[np.intp], npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """SpineBase, every root-to-leaf path of joints (padded with the leaf), and per joint the
    path holding it and its depth on that path."""
    parent_of = {int(child): int(parent) for parent, child in BONES}
    root = next(iter({*parent_of.values()} - {*parent_of}))
    leaves = sorted({*parent_of} - {*parent_of.values()})
    paths = []
    for leaf in leaves:
        path = [leaf]
        while path[-1] != root:
            path.append(parent_of[path[-1]])
        paths.append(path[::-1])
    width = max(len(path) for path in paths)
    padded = np.array([path + [path[-1]] * (width - len(path)) for path in paths], dtype=np.intp)
    path_of = np.zeros(len(parent_of) + 1, dtype=np.intp)
    depth_of = np.zeros(len(parent_of) + 1, dtype=np.intp)
    for k, path in enumerate(paths):
        for depth, joint in enumerate(path):
            path_of[joint], depth_of[joint] = k, depth
    return root, padded, path_of, depth_of


_ROOT, _PATHS, _PATH_OF, _DEPTH_OF = _chain_paths()
_SOURCE_OF: Final = np.zeros(len(_PATH_OF), dtype=np.intp)
_SOURCE_OF[_BONE_CHILD] = 1 + np.arange(BONE_COUNT)
"""Per joint, its row in ``enforce_bone_lengths``' sources: 0 SpineBase, 1 + the bone ending
there."""
_PATH_SOURCES: Final = _SOURCE_OF[_PATHS]
_PATH_INDEX: Final = _PATH_OF * _PATHS.shape[1] + _DEPTH_OF
"""Per joint, where its running sum lies in the flattened (paths × depth) sums."""


def _bone_groups() -> tuple[npt.NDArray[np.intp], ...]:
    """Bones split into groups that share no joint (a greedy edge colouring of the tree), so a
    group's corrections can be applied at once without two bones writing the same joint."""
    groups: list[list[int]] = []
    used: list[set[int]] = []
    for b, (parent, child) in enumerate(BONES):
        for group, joints in zip(groups, used, strict=True):
            if parent not in joints and child not in joints:
                group.append(b)
                joints.update((parent, child))
                break
        else:
            groups.append([b])
            used.append({parent, child})
    return tuple(np.array(g, dtype=np.intp) for g in groups)


BONE_GROUPS: Final = _bone_groups()
_GROUPED: Final = np.concatenate(BONE_GROUPS)
_GROUPED_PARENT: Final = _BONE_PARENT[_GROUPED]
_GROUPED_CHILD: Final = _BONE_CHILD[_GROUPED]
_GROUP_BOUNDS: Final = np.cumsum([0] + [len(g) for g in BONE_GROUPS]).tolist()
_GROUP_ENDS: Final = tuple(
    (np.stack([_BONE_PARENT[g], _BONE_CHILD[g]]), lo, hi)
    for g, lo, hi in zip(BONE_GROUPS, _GROUP_BOUNDS[:-1], _GROUP_BOUNDS[1:], strict=True)
)
"""Per group: its bones' (parents, children) as a (2, n) index array, and its slice of
:data:`_GROUPED` (the bones in group order)."""


def project_bone_lengths(
    joints: npt.ArrayLike,
    reference: npt.ArrayLike,
    mobility: npt.ArrayLike | None = None,
    iterations: int = 3,
) -> FloatArray:
    """Give a skeleton the reference bone lengths while moving its joints as little as possible.

    Position-based distance constraints: each pass shortens or lengthens every bone to its
    reference by moving both ends along the bone, the parent by the share ``m_p / (m_p + m_c)``
    of the mobilities; ``iterations`` passes (Gauss–Seidel over :data:`BONE_GROUPS`) then one
    outward :func:`enforce_bone_lengths` pass make the lengths exact. Unlike that pass alone,
    which keeps SpineBase fixed and pushes a whole subtree along with every correction, the
    correction is spread over both ends, so errors do not pile up towards the hands and feet.

    Args:
        joints: (..., 25, 3) metres. reference: (..., 24) metres in :data:`BONES` order, NaN for
            a bone to leave alone. mobility: (..., 25) how freely each joint may move (> 0;
            e.g. 1 − confidence); None: all alike.

    Returns:
        (..., 25, 3) float64; NaN joints stay NaN.
    """
    original = np.asarray(joints, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    if mobility is None:  # all alike: ones, which the floor below leaves as they are
        move = np.ones(original.shape[:-1])
    else:
        move = np.maximum(np.asarray(mobility, np.float64), 1e-6)
    if kernels.enabled():  # the same bits in one compiled loop; the code below is the reference
        return kernels.project_bone_lengths(original, ref, move, iterations, BONE_TABLES)
    missing = np.asarray(~np.isfinite(original).all(axis=-1))  # (..., 25)
    out = np.where(missing[..., None], 0.0, original)  # NaN-free while iterating
    # Fixed over the passes, for all bones at once in group order: each bone's target and its
    # ends' shares (0 for a bone with an unknown target or a missing end: it moves nothing).
    target = ref[..., _GROUPED]
    usable = np.isfinite(target) & ~missing[..., _GROUPED_PARENT] & ~missing[..., _GROUPED_CHILD]
    m_parent, m_child = move[..., _GROUPED_PARENT], move[..., _GROUPED_CHILD]
    share = np.where(usable, m_parent / (m_parent + m_child), 0.0)[..., None]
    rest = np.where(usable, 1.0, 0.0)[..., None] - share
    # Joints first while iterating, so that a group's ends are whole rows (the cheapest
    # gather and scatter); per group, both ends in one array (2, n, ..., 3). The parent moves
    # by share·delta, the child by −rest·delta (adding the negated product is the subtraction,
    # to the bit).
    coefficients = np.moveaxis(np.stack([share, -rest]), -2, 1)  # (2, 24, ..., 1)
    target = np.moveaxis(np.where(usable, target, 0.0), -1, 0)  # (24, ...)
    plan = [(ends, target[lo:hi], coefficients[:, lo:hi]) for ends, lo, hi in _GROUP_ENDS]
    rows = np.moveaxis(out, -2, 0).copy()  # (25, ..., 3)
    for _ in range(iterations):
        for ends, group_target, coefficient in plan:
            both = rows.take(ends, axis=0)  # (2, n, ..., 3): parents, children
            offsets = both[1] - both[0]
            norms = np.maximum(np.sqrt(np.vecdot(offsets, offsets)), 1e-12)
            delta = offsets * ((norms - group_target) / norms)[..., None]
            rows[ends] = both + coefficient * delta
    out = np.moveaxis(rows, 0, -2)
    out[missing] = np.nan
    return enforce_bone_lengths(out, ref)


_BONE_TO_JOINT: Final = _SOURCE_OF - 1
_BONE_TO_JOINT[_ROOT] = -1
BONE_TABLES: Final = (
    _GROUPED,
    _BONE_PARENT,
    _BONE_CHILD,
    np.array(CHAIN_ORDER, dtype=np.intp),
    np.array([max(parent, 0) for parent in PARENTS], dtype=np.intp),
    _BONE_TO_JOINT,
)
"""The index tables of :func:`skelfuse.fusion.kernels_bones.project_loop`: the bones in group
order, each bone's parent and child, the joints parents first, each joint's parent (SpineBase:
itself, unused) and the bone ending at each joint (−1: SpineBase)."""

BoneSource = Literal["set", "estimated", "none"]


class BoneModel:
    """A person's reference bone lengths: set by hand, or estimated online.

    The online estimate is, per bone, the median of the last ``window`` observations from good
    views (both ends Tracked, the person facing the sensor within 60°, after mirror
    correction). A bone that good views have not shown ``min_samples`` times yet (hand tips and
    thumbs, often) takes the median of any view where both ends are Tracked instead. With
    ``symmetric``, a left bone and its right counterpart share their observations: people are
    left-right symmetric to a percent or two, and twice the samples settle the estimate sooner.
    The estimate is refreshed every step while it settles, then every ``_REFRESH_EVERY`` steps.
    """

    _REFRESH_EVERY = 10

    def __init__(
        self,
        window: int = 300,
        min_samples: int = 30,
        symmetric: bool = True,
        lock_samples: int | None = None,
    ) -> None:
        self.set_lengths: FloatArray | None = None
        self.min_samples = min_samples
        self.symmetric = symmetric
        self.lock_samples = lock_samples
        self._locked = np.zeros(BONE_COUNT, dtype=bool)
        self._samples = SampleWindow(window)
        self._fallback = SampleWindow(window)
        self._estimate = np.full(BONE_COUNT, np.nan)
        self._since_update = 0

    @property
    def source(self) -> BoneSource:
        if self.set_lengths is not None:
            return "set"
        return "estimated" if np.isfinite(self._estimate).any() else "none"

    @property
    def estimate(self) -> FloatArray:
        """(24,) online estimate, metres; NaN for bones without enough observations."""
        return self._estimate.copy()

    def reference(self) -> FloatArray:
        """(24,) the lengths fusion uses: the set ones, else the estimate (NaN: unknown)."""
        return self.set_lengths.copy() if self.set_lengths is not None else self.estimate

    def observe(self, lengths: FloatArray, fallback: FloatArray | None = None) -> None:
        """Add one step's observed lengths.

        Args:
            lengths: (24,) metres from good views, NaN for bones not observed well.
            fallback: (24,) metres from any view with both ends Tracked, or None.
        """
        good = bool(np.isfinite(lengths).any())
        spare = fallback is not None and bool(np.isfinite(fallback).any())
        self._add(lengths if good else None, fallback if spare else None)

    def _add(self, lengths: FloatArray | None, fallback: FloatArray | None) -> None:
        """:meth:`observe` once it is known which of the two hold any length (None: none)."""
        if lengths is None and fallback is None:
            return
        if lengths is not None:
            self._samples.append(lengths)
        if fallback is not None:
            self._fallback.append(fallback)
        self._since_update += 1
        settling = len(self._samples) < 2 * self.min_samples
        if settling or self._since_update >= self._REFRESH_EVERY:
            self._since_update = 0
            estimate, counts = self._samples.median(self.min_samples, self.symmetric)
            missing = ~np.isfinite(estimate)
            if missing.any():
                backup = self._fallback.median(self.min_samples, self.symmetric)[0]
                estimate[missing] = backup[missing]
            self._estimate = np.where(self._locked, self._estimate, estimate)
            if self.lock_samples is not None:
                self._locked |= counts >= self.lock_samples

    def mirror(self) -> None:
        """Swap left and right in the online samples (the track they came from was mirrored)."""
        self._samples.mirror()
        self._fallback.mirror()
        self._estimate = self._estimate[_BONE_MIRROR]
        self._locked = self._locked[_BONE_MIRROR]


def references_of(models: list[BoneModel]) -> FloatArray:
    """(P, 24) each model's :meth:`BoneModel.reference` (P >= 1), without a copy of each."""
    rows = [m.set_lengths if m.set_lengths is not None else m._estimate for m in models]
    return np.array(rows, dtype=np.float64)


def observe_bone_lengths(
    models: list[BoneModel],
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    cosines: FloatArray,
    person_of: npt.NDArray[np.intp],
    slot_of: npt.NDArray[np.intp],
    widest: int,
) -> None:
    """Feed each person's online estimate with this step's views of that person.

    Args:
        models: one per person (P).
        joints: (N, 25, 3) all persons' views, metres, labels corrected; states: (N, 25).
        cosines: (N,) each view's facing cosine: good views face their sensor within 60°.
        person_of, slot_of: (N,) each view's person and its index among that person's views.
        widest: the most views any person has.
    """
    estimating = [model.set_lengths is None for model in models]
    if not any(estimating):
        return
    if kernels.enabled() and kernels_observe.warmed():  # the same bits in one loop
        per_bone = kernels_observe.bone_medians(
            joints, states, cosines, person_of, len(models), _BONE_ENDS, _TRACKED, GOOD_VIEW_COS
        )
    else:
        per_bone = per_bone_medians(
            joints, states, cosines, person_of, slot_of, len(models), widest
        )
    # (persons, 2): whether any good view, and any view at all, shows some bone
    seen: list[list[bool]] = np.logical_or.reduce(np.isfinite(per_bone), axis=2).tolist()
    for p, ((good, spare), wanted) in enumerate(zip(seen, estimating, strict=True)):
        if spare and wanted:  # a person with no usable view at all adds nothing
            models[p]._add(per_bone[p, 0] if good else None, per_bone[p, 1])


def per_bone_medians(
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    cosines: FloatArray,
    person_of: npt.NDArray[np.intp],
    slot_of: npt.NDArray[np.intp],
    persons: int,
    widest: int,
) -> FloatArray:
    """(persons, 2, 24) per person and bone the median length (metres) over its good views
    ([.., 0]) and over any view with both ends Tracked ([.., 1]); NaN where none shows it.

    Args: as :func:`observe_bone_lengths`; persons: P.
    """
    good_view = np.isfinite(cosines) & (cosines >= GOOD_VIEW_COS)
    tracked = states == _TRACKED
    both_tracked = tracked[:, _BONE_PARENT] & tracked[:, _BONE_CHILD]
    bones = joints[:, _BONE_CHILD] - joints[:, _BONE_PARENT]
    # What np.linalg.norm(bones, axis=-1) computes, without its checks and copies.
    lengths = np.sqrt(np.add.reduce(bones * bones, axis=-1))
    any_view = np.where(both_tracked & np.isfinite(lengths), lengths, np.nan)
    # (persons, 2, bones, views): good views only, then any view; views last, so that the
    # median sorts contiguous rows.
    padded = np.full((persons, 2, BONE_COUNT, widest), np.nan)
    padded[person_of, 0, :, slot_of] = np.where(good_view[:, None], any_view, np.nan)
    padded[person_of, 1, :, slot_of] = any_view
    return nanmedian_last(padded)


def fit_bone_lengths(
    skeletons: FloatArray, references: FloatArray, method: BoneFit, iterations: int
) -> FloatArray:
    """Give each skeleton its person's reference lengths, by the method the settings name.

    Args:
        skeletons: (P, 25, 3) metres; references: (P, 24) metres (NaN: leave that bone).
        method: ``projection`` (:func:`project_bone_lengths`, both ends of each bone move) or
            ``chain`` (:func:`enforce_bone_lengths`, outward from SpineBase).
        iterations: passes of the projection.

    Returns:
        (P, 25, 3) float64.
    """
    if method == "chain":
        return enforce_bone_lengths(skeletons, references)
    return project_bone_lengths(skeletons, references, iterations=iterations)
