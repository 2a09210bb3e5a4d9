"""The mirror labels' scoring and what follows the choice: the parts asked for, in any step
(persons never fused, unknown facings), the views swapped back in place whatever their layout,
the facings of the swapped views, and each person's memory of its labels.
"""

from __future__ import annotations

from dataclasses import replace
from itertools import pairwise
from typing import Any

import numpy as np
import pytest

from skelfuse.fusion import labels
from skelfuse.fusion.labels import LabelDoubt, label_views, unbiased_facings
from skelfuse.fusion.mirror import PERMUTATION, Scored
from skelfuse.fusion.settings import FusionSettings
from tests.unit.test_mirror_scores import Frame, _frame


def _scored(
    frame: Frame, settings: FusionSettings, need_rom: bool = True, evidence: bool = True
) -> Scored:
    previous = np.asarray(frame.previous, dtype=np.intp)
    return labels.scored_labels(
        frame.views.copy(),
        frame.sensor_positions,
        frame.counts,
        frame.references,
        frame.reference_facings,
        previous,
        settings,
        need_rom=need_rom,
        want_evidence=evidence,
    )


@pytest.mark.parametrize(
    ("edit", "need_rom"), [("none", True), ("reference", True), ("facing", True), ("none", False)]
)
def test_the_scoring_gives_what_was_asked_for_any_step(edit: str, need_rom: bool) -> None:
    frame = _frame(2)
    settings = FusionSettings()
    if edit == "reference":
        frame = replace(frame, references=[None, *frame.references[1:]])
    elif edit == "facing":
        facings = frame.reference_facings.copy()
        facings[3] = np.nan
        frame = replace(frame, reference_facings=facings)
    if not need_rom:
        settings = replace(settings, mirror=replace(settings.mirror, anatomy_weight_m=0.0))
    got = _scored(frame, settings, need_rom=need_rom, evidence=need_rom)
    assert got.mirrored.any() and not got.mirrored.all()
    if not need_rom:
        assert got.factors is None and got.per_view is None and got.evidence is None
        return
    assert got.factors is not None and got.per_view is not None and got.evidence is not None
    np.testing.assert_array_equal(got.per_view, labels.view_evidence(got.factors, got.mirrored))
    np.testing.assert_allclose(
        got.evidence, labels.evidence_against(got.factors, got.mirrored, frame.counts)
    )


def test_the_evidence_is_left_out_unless_wanted() -> None:
    frame = replace(_frame(1), references=[None, *_frame(1).references[1:]])
    got = _scored(frame, FusionSettings(), evidence=False)
    assert got.factors is not None and got.per_view is None and got.evidence is None


def _label(frame: Frame, states_order: str = "C") -> tuple[Any, ...]:
    """label_views on a copy of ``frame`` with remembered labels and running doubts."""
    rng = np.random.default_rng(7)
    joints = frame.views.copy()
    states = np.asarray(rng.integers(0, 3, joints.shape[:2]), dtype=np.uint8, order=states_order)
    keys = [(f"s{i % 4}", i) for i in range(len(joints))]
    starts = np.cumsum((0, *frame.counts))
    memories = [
        {k: bool(rng.integers(0, 2)) for k in keys[lo:hi]} for lo, hi in pairwise(starts.tolist())
    ]
    doubts = [LabelDoubt(against=1.4, born_s=-5.0, last_s=-1 / 30) for _ in frame.counts]
    doubts[1].facing = np.array([0.0, 0.0, 1.0])  # a remembered unbiased facing
    mirrored, rom, swapped = label_views(
        joints, states, frame.sensor_positions, keys, frame.counts, frame.references,
        frame.reference_facings, memories, FusionSettings(), doubts, 0.0,
    )  # fmt: skip
    facings = np.array([d.facing for d in doubts])
    return mirrored, rom, swapped, joints, states, facings, memories, [d.against for d in doubts]


@pytest.mark.parametrize("seed", range(4))
def test_the_labels_after_the_choice_swap_back_and_give_the_facings_of_the_swapped_views(
    seed: int,
) -> None:
    frame = _frame(seed)
    got = _label(frame, "C")
    mirrored, rom, _, joints, _, facings, _, _ = got
    expected = frame.views.copy()
    expected[mirrored] = expected[mirrored][:, PERMUTATION]
    assert np.array_equal(joints, expected, equal_nan=True)
    lean = FusionSettings().weights.view_lean_fraction
    remade = unbiased_facings(joints, frame.sensor_positions, mirrored, frame.counts, lean)
    np.testing.assert_allclose(facings, remade, rtol=0, atol=1e-12)  # from the swapped joints
    assert rom is not None and rom.shape == (len(joints), 25)
    fortran = _label(frame, "F")  # states in another layout: the same labels, in place
    for a, b in zip(got, fortran, strict=True):
        if isinstance(a, np.ndarray):
            assert np.array_equal(a, b, equal_nan=True)
        else:
            assert a == b
    assert mirrored.any() and np.isfinite(facings).all()


def test_each_person_remembers_exactly_this_steps_labels() -> None:
    """Kept as they are when decided again, replaced otherwise, and a body gone is forgotten."""
    frame = _frame(3)
    keys = [(f"s{i % 4}", i) for i in range(len(frame.views))]
    starts = np.cumsum((0, *frame.counts)).tolist()
    memories: list[dict[tuple[str, int], bool]] = [{} for _ in frame.counts]
    for step in range(3):
        if step == 2:
            memories[0][("gone", 99)] = True  # a body no view shows any more
            memories[1] = {k: not m for k, m in memories[1].items()}  # labels turned over
        mirrored, _, _ = label_views(
            frame.views.copy(), np.full(frame.views.shape[:2], 2, np.uint8),
            frame.sensor_positions, keys, frame.counts, frame.references,
            frame.reference_facings, memories, FusionSettings(), None, step / 30,
        )  # fmt: skip
        flags = mirrored.tolist()
        for p, (lo, hi) in enumerate(pairwise(starts)):
            assert memories[p] == dict(zip(keys[lo:hi], flags[lo:hi], strict=True)), (step, p)
