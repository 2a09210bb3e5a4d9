"""The mirror labels' scoring, and what follows the choice, in one compiled call each give the
bits of the calls one by one.

skelfuse.fusion.label_scores.scored_labels runs the usual step (every person's last skeleton
and facing known) as one call (skelfuse.fusion.kernels_label_stage); anything else runs
choose_labellings_and_forward and the evidence apart. Both are compared, bit for bit, with the
numpy code on frames with ties, mirror images, views that see nothing, a sensor where the body
stands, and persons of 1 to 10 views (screened from 6).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from itertools import pairwise
from typing import Any

import numpy as np
import pytest

from skelfuse.fusion import kernels, kernels_label_stage, label_scores
from skelfuse.fusion.labels import LabelDoubt, label_views
from skelfuse.fusion.mirror import PERMUTATION
from skelfuse.fusion.settings import FusionSettings
from skelfuse.fusion.unbiased_facing import unbiased_facings
from tests.unit.test_kernels import _numpy_uses_svml, _same_bits
from tests.unit.test_kernels_mirror import Frame, _frame


def _scored(
    frame: Frame, settings: FusionSettings, mode: str, need_rom: bool = True, evidence: bool = True
) -> label_scores.Scored:
    previous = np.asarray(frame.previous, dtype=np.intp)
    with kernels.forced(mode):
        return label_scores.scored_labels(
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


def _same(got: label_scores.Scored, expected: label_scores.Scored) -> None:
    assert _same_bits(got.mirrored, expected.mirrored)
    for name in ("factors", "forward", "per_view", "evidence"):
        a, b = getattr(got, name), getattr(expected, name)
        assert (a is None) == (b is None), name
        if a is None:
            continue
        if _numpy_uses_svml():  # numpy's own arccos / arctan2 on AVX-512: a few ulp apart
            np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12, err_msg=name)
        else:
            assert _same_bits(a, b), name


def _spy(monkeypatch: pytest.MonkeyPatch, name: str = "scored") -> list[int]:
    """Count the calls of ``kernels_label_stage.<name>`` (one 1 per call)."""
    calls: list[int] = []
    original: Callable[..., Any] = getattr(kernels_label_stage, name)

    def spied(*args: Any) -> Any:
        calls.append(1)
        return original(*args)

    monkeypatch.setattr(kernels_label_stage, name, spied)
    return calls


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize(
    "change",
    [
        {},
        {"mirror_anatomy_weight_m": 0.0},
        {"mirror_hysteresis_m": 0.0, "mirror_track_weight": 0.5},
        {"rom_scale_deg": 7.5, "mirror_geometry_weight_m": 0.3},
    ],
)
def test_the_compiled_scoring_gives_the_bits_of_the_calls_apart(
    numba_kernels: None, monkeypatch: pytest.MonkeyPatch, seed: int, change: dict[str, Any]
) -> None:
    settings = replace(FusionSettings(), **change)
    frame = _frame(seed)
    calls = _spy(monkeypatch)
    got = _scored(frame, settings, "numba")
    assert calls == [1]  # the usual step: one compiled call
    expected = _scored(frame, settings, "numpy")
    _same(got, expected)
    assert got.mirrored.any() and not got.mirrored.all()  # both labellings were chosen
    assert got.per_view is not None and (got.per_view != 0).any()


@pytest.mark.parametrize(
    ("case", "edit", "need_rom"),
    [
        ("a person never fused", "reference", True),
        ("a facing unknown", "facing", True),
        ("neither the anatomy term nor the factors wanted", "none", False),
    ],
)
def test_any_other_step_scores_the_calls_apart_with_the_same_bits(
    numba_kernels: None, monkeypatch: pytest.MonkeyPatch, case: str, edit: str, need_rom: bool
) -> None:
    frame = _frame(2)
    settings = FusionSettings()
    if edit == "reference":
        frame = replace(frame, references=[None, *frame.references[1:]])
    elif edit == "facing":
        facings = frame.reference_facings.copy()
        facings[3] = np.nan
        frame = replace(frame, reference_facings=facings)
    else:
        settings = replace(settings, mirror_anatomy_weight_m=0.0)
    calls = _spy(monkeypatch)
    got = _scored(frame, settings, "numba", need_rom=need_rom, evidence=need_rom)
    assert calls == [], case
    expected = _scored(frame, settings, "numpy", need_rom=need_rom, evidence=need_rom)
    _same(got, expected)
    if not need_rom:
        assert got.factors is None and got.per_view is None


def test_the_evidence_is_left_out_unless_wanted(numba_kernels: None) -> None:
    frame = replace(_frame(1), references=[None, *_frame(1).references[1:]])
    got = _scored(frame, FusionSettings(), "numba", evidence=False)
    assert got.factors is not None and got.per_view is None and got.evidence is None


def test_the_compiled_call_waits_for_its_warm_up(
    numba_kernels: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(kernels_label_stage.warmed, "done", False)
    calls = _spy(monkeypatch)
    got = _scored(_frame(0), FusionSettings(), "numba")
    assert calls == []  # no frame waits for a compilation
    _same(got, _scored(_frame(0), FusionSettings(), "numpy"))


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
    lean = FusionSettings().view_lean_fraction
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
