"""Steps 5–6 in one compiled call give the bits of the step term by term.

skelfuse.fusion.weigh.weigh_and_fuse runs the usual step as one call
(skelfuse.fusion.kernels_weigh); anything else runs term by term. Both are compared, bit for
bit, with the numpy code on simulated views with noise, unknown joints, unknown sensor
positions and facings, persons with different numbers of views, and each rare case that must
leave the compiled call.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from skelfuse.fusion import kernels, kernels_weigh, weigh
from skelfuse.fusion.batch import ViewBatch
from skelfuse.fusion.priors import SensorPrior, priors_of
from skelfuse.fusion.settings import FusionSettings
from skelfuse.fusion.views import View
from skelfuse.protocol.skeleton import BONES, JointId
from tests.unit.test_kernels import _numpy_uses_svml, _same_bits, _views

COUNTS = (4, 2, 3, 1, 4)
"""Views per person: different widths, so the persons are padded, and a person seen once."""


def _batch(seed: int, sensor_type: str = "kinect_v2") -> ViewBatch:
    rng = np.random.default_rng(seed)
    joints = _views(seed)
    states = rng.integers(0, 3, joints.shape[:2]).astype(np.uint8)
    sensors = rng.uniform(-4.0, 4.0, (len(joints), 3))
    sensors[rng.random(len(joints)) < 0.1] = np.nan  # sensors whose position is unknown
    clusters: list[list[View]] = []
    row = 0
    for count in COUNTS:
        own = []
        for k in range(count):
            joints[row, JointId.SPINE_BASE] = rng.normal(0.0, 0.5, 3) + [0.0, 1.0, 2.0]
            states[row, JointId.SPINE_BASE] = 2  # Tracked: every person stands somewhere
            own.append(View(f"s{k}", row, joints[row], states[row], sensors[row], sensor_type))
            row += 1
        clusters.append(own)
    return ViewBatch.of(clusters)


def _inputs(seed: int, batch: ViewBatch) -> tuple[Any, ...]:
    rng = np.random.default_rng(seed + 100)
    persons = len(batch.counts)
    references = rng.uniform(0.05, 0.5, (persons, len(BONES)))
    references[rng.random(references.shape) < 0.2] = np.nan
    references[1] = np.nan  # a person without reference lengths yet
    angle = rng.uniform(0, 2 * np.pi, persons)
    facings = np.stack([np.sin(angle), np.zeros(persons), np.cos(angle)], axis=1)
    facings[2] = np.nan  # a track whose facing is unknown
    rom = rng.uniform(0.2, 1.0, batch.joints.shape[:2])
    return rom, references, facings


def _run(
    batch: ViewBatch, fused_once: list[bool], settings: FusionSettings, seed: int, mode: str
) -> tuple[weigh.Weighed, ViewBatch]:
    own = copy.deepcopy(batch)  # (correct_view_yaw turns the joints in place)
    rom, references, facings = _inputs(seed, own)
    priors = priors_of([v.sensor_type for v in own.views]) if settings.use_sensor_priors else None
    with kernels.forced(mode):
        got = weigh.weigh_and_fuse(own, rom, references, facings, fused_once, settings, priors)
    return got, own


def _same(got: weigh.Weighed, expected: weigh.Weighed) -> None:
    for name, a, b in zip(got._fields, got, expected, strict=True):
        if _numpy_uses_svml() and a.dtype == np.float64:  # numpy's own exp on AVX-512
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=0.0, err_msg=name)
        else:
            assert _same_bits(a, b), name


def _spy(monkeypatch: pytest.MonkeyPatch) -> list[bool]:
    """Record each compiled call's outcome (True: it computed the step)."""
    calls: list[bool] = []
    original: Callable[..., Any] = kernels_weigh.weigh_and_fuse

    def spied(*args: Any) -> Any:
        result = original(*args)
        calls.append(result is not None)
        return result

    monkeypatch.setattr(kernels_weigh, "weigh_and_fuse", spied)
    return calls


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize(
    "change",
    [{}, {"use_bone_length": False}, {"use_range_of_motion": False}, {"facing_power": 1.5}],
)
def test_the_compiled_step_gives_the_numpy_bits(
    numba_kernels: None, monkeypatch: pytest.MonkeyPatch, seed: int, change: dict[str, Any]
) -> None:
    settings = replace(FusionSettings(), **change)
    batch = _batch(seed)
    calls = _spy(monkeypatch)
    got, _ = _run(batch, [True] * len(COUNTS), settings, seed, "numba")
    assert calls == [True]  # the compiled call ran, and did the step
    expected, _ = _run(batch, [True] * len(COUNTS), settings, seed, "numpy")
    _same(got, expected)
    # The terms reached the result: weights below the state table's, views that did not carry.
    assert (got.weights[got.weights > 0] < 0.5).any() and not got.carried.all()
    assert np.isnan(got.cosines).any() and np.isfinite(got.fused).any()


@pytest.mark.parametrize("seed", range(3))
def test_a_person_whose_spine_no_view_sees_leaves_the_compiled_call(
    numba_kernels: None, monkeypatch: pytest.MonkeyPatch, seed: int
) -> None:
    batch = _batch(seed)
    batch.joints[4:6, JointId.SPINE_BASE] = np.nan  # every view of the second person
    calls = _spy(monkeypatch)
    got, _ = _run(batch, [True] * len(COUNTS), FusionSettings(), seed, "numba")
    assert calls == [False]  # it stands at its views' mean SpineBase: the general code's
    expected, _ = _run(batch, [True] * len(COUNTS), FusionSettings(), seed, "numpy")
    _same(got, expected)
    assert np.isnan(got.fused[1, JointId.SPINE_BASE]).all()


@pytest.mark.parametrize(
    ("case", "change", "fused_once", "sensor_type"),
    [
        ("a person fused the first time", {}, [True, False, True, True, True], "kinect_v2"),
        ("the distance term", {"use_distance": True}, [True] * 5, "kinect_v2"),
        ("the yaw correction", {"correct_view_yaw": True}, [True] * 5, "kinect_v2"),
        ("the view reliability", {"use_view_reliability": True}, [True] * 5, "kinect_v2"),
        ("the Cauchy pass", {"outlier_scale_m": 0.05}, [True] * 5, "kinect_v2"),
        ("no facing term", {"use_facing": False}, [True] * 5, "kinect_v2"),
        ("a camera that guesses depth", {}, [True] * 5, "rgb"),
        ("a sensor prior's own table", {}, [True] * 5, "azure_kinect"),
    ],
)
def test_every_other_step_runs_term_by_term_with_the_same_bits(
    numba_kernels: None,
    monkeypatch: pytest.MonkeyPatch,
    case: str,
    change: dict[str, Any],
    fused_once: list[bool],
    sensor_type: str,
) -> None:
    settings = replace(FusionSettings(), **change)
    batch = _batch(3, sensor_type)
    priors = priors_of([v.sensor_type for v in batch.views])
    if sensor_type == "azure_kinect":  # (its prior must differ from the settings to count)
        assert any(p != SensorPrior("kinect_v2") for p in priors)
    calls = _spy(monkeypatch)
    got, _ = _run(batch, fused_once, settings, 3, "numba")
    assert calls == [], case  # not asked at all
    expected, _ = _run(batch, fused_once, settings, 3, "numpy")
    _same(got, expected)


def test_the_compiled_call_waits_for_its_warm_up(
    numba_kernels: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(kernels_weigh.warmed, "done", False)
    calls = _spy(monkeypatch)
    got, _ = _run(_batch(0), [True] * len(COUNTS), FusionSettings(), 0, "numba")
    assert calls == []  # no frame waits for a compilation
    expected, _ = _run(_batch(0), [True] * len(COUNTS), FusionSettings(), 0, "numpy")
    _same(got, expected)
