"""A run's progress and time left (server/calibration_run_progress.py) on a fake clock: the bar
never goes back while its split moves to measured rates, time left comes from measurements only,
and a stage marked not to be measured (the solver process starting) leaves the rates alone."""

from __future__ import annotations

import pytest

from skelfuse.server.calibration_run_progress import (
    DEPTH,
    ICP,
    PRIOR_S_PER_UNIT,
    SKELETONS,
    STAGES,
    WALK,
    RunProgress,
    StageRates,
)


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def time(self) -> float:
        return self.now

    def monotonic(self) -> float:
        return self.now

    async def sleep(self, seconds: float) -> None:
        self.now += seconds


UNITS = {WALK: 10.0, SKELETONS: 1, DEPTH: 1, ICP: 4}


def walk_through(
    progress: RunProgress, clock: Clock, durations: dict[str, float], measure_solve: bool = True
) -> list[tuple[float, float | None]]:
    """Every stage in turn, reporting ten steps each; (progress, eta_s) at every step."""
    seen = []
    for stage in progress.stages:
        progress.enter(stage, measure=measure_solve or stage != SKELETONS)
        for step in range(1, 11):
            clock.now += durations[stage] / 10
            if stage in (WALK, ICP):  # the stages with inner steps
                progress.advance(step / 10)
            seen.append((progress.progress, progress.eta_s()))
    progress.finish()
    return seen


def test_first_run_splits_by_priors_and_knows_time_left_only_inside_measured_stages() -> None:
    clock, rates = Clock(), StageRates()
    progress = RunProgress(STAGES["auto"], UNITS, rates, clock)
    seen = walk_through(progress, clock, {WALK: 10, SKELETONS: 2, DEPTH: 3, ICP: 20})
    shares = [p for p, _ in seen]
    assert shares == sorted(shares) and progress.progress == 1.0 and progress.eta_s() == 0.0
    expected = [10.0 * 1, UNITS[SKELETONS] * PRIOR_S_PER_UNIT[SKELETONS]]
    expected += [UNITS[DEPTH] * PRIOR_S_PER_UNIT[DEPTH], UNITS[ICP] * PRIOR_S_PER_UNIT[ICP]]
    assert shares[9] == pytest.approx(10.0 / sum(expected))  # the walk's share, priors after
    assert all(eta is None for _, eta in seen[:30])  # nothing measured yet after the walk
    icp = [eta for _, eta in seen[30:]]
    assert icp[0] == pytest.approx(18.0) and icp[-1] == pytest.approx(0.0)  # 2 s of 20 done
    assert icp == sorted(icp, reverse=True)


def test_second_run_knows_its_time_left_from_the_start_and_splits_by_measurements() -> None:
    clock, rates = Clock(), StageRates()
    durations = {WALK: 10.0, SKELETONS: 2.0, DEPTH: 3.0, ICP: 20.0}
    walk_through(RunProgress(STAGES["auto"], UNITS, rates, clock), clock, durations)
    progress = RunProgress(STAGES["auto"], UNITS, rates, clock)
    seen = walk_through(progress, clock, durations)
    assert seen[0][1] == pytest.approx(35.0 - 1.0)  # 1 s of the walk done
    assert seen[9][0] == pytest.approx(10.0 / 35.0)  # the walk's measured share
    etas = [eta for _, eta in seen]
    assert all(eta is not None for eta in etas)
    assert etas == sorted(etas, reverse=True)  # as long as the rates hold


def test_an_unmeasured_stage_keeps_the_rate_before_it() -> None:
    clock, rates = Clock(), StageRates()
    durations = {WALK: 10.0, SKELETONS: 2.0, DEPTH: 3.0, ICP: 20.0}
    walk_through(RunProgress(STAGES["auto"], UNITS, rates, clock), clock, durations)
    slow = {**durations, SKELETONS: 40.0}  # e.g. the solver process started meanwhile
    progress = RunProgress(STAGES["auto"], UNITS, rates, clock)
    walk_through(progress, clock, slow, measure_solve=False)
    assert rates.measured(SKELETONS) == pytest.approx(2.0)


def test_failure_keeps_the_stage_and_progress() -> None:
    clock, rates = Clock(), StageRates()
    progress = RunProgress(STAGES["icp"], UNITS, rates, clock)
    progress.enter(DEPTH)
    progress.enter(ICP)
    progress.advance(0.5)
    before = progress.progress
    progress.advance(0.2)  # a smaller report: kept at the larger
    assert progress.progress == before
    progress.fail()
    report = progress.to_json()
    assert report["stage"] == "failed" and report["stage_index"] == 1
    assert report["progress"] == round(before, 3) and report["eta_s"] is None
