"""The compiled fusion kernels give the same bits as their numpy reference, on random inputs.

Each kernel (skelfuse.fusion.kernels) is run against the numpy code it replaces, on skeletons
from the simulator with noise, unknown joints, whole missing trunks and plain random points;
the results must be byte-identical (the kernels repeat numpy's operations in its order). The
golden replay (test_golden_replay.py) is run with the kernels on and off in the same way.
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import numpy as np
import pytest

from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.fusion import anatomy, kernels, weighted
from skelfuse.protocol.skeleton import JointId as J
from tests.support import require_numba
from tests.unit import test_golden_replay as golden

FloatArray = np.ndarray


def _views(seed: int) -> FloatArray:
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


def _same_bits(a: FloatArray, b: FloatArray) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def _numpy_uses_svml() -> bool:
    """Whether numpy's arcsin / arccos / arctan2 run Intel's SVML (AVX-512 machines): they are
    then a few ulp from the C library's, which the kernel calls, so bit equality cannot hold."""
    try:
        umath = importlib.import_module("numpy._core._multiarray_umath")
    except ImportError:  # numpy < 2
        umath = importlib.import_module("numpy.core._multiarray_umath")
    return bool(getattr(umath, "__cpu_features__", {}).get("AVX512_SKX", False))


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("scale_deg", [15.0, 7.5])
def test_rom_kernel_gives_the_numpy_bits(numba_kernels: None, seed: int, scale_deg: float) -> None:
    views = _views(seed)
    factors, forward = anatomy.rom_factors_and_forward(views, scale_deg)
    with kernels.forced("numpy"):
        assert not kernels.enabled()
        expected_factors, expected_forward = anatomy.rom_factors_and_forward(views, scale_deg)
    if _numpy_uses_svml():  # angles from trigonometry: a few ulp apart, never more
        np.testing.assert_allclose(factors, expected_factors, rtol=1e-12, atol=0.0)
    else:
        assert _same_bits(factors, expected_factors)
    assert _same_bits(forward, expected_forward)  # sums, products and sqrt only: exact anywhere
    assert (factors < 1.0).any() and np.isnan(forward).any()  # the inputs reach every branch


def test_forcing_numpy_turns_the_kernels_off(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(kernels.ENV, "numpy")
    assert kernels.mode() == "numpy" and not kernels.enabled()
    assert kernels.warm_up() == 0.0
    monkeypatch.setenv(kernels.ENV, "fortran")
    with pytest.raises(ValueError, match="SKELFUSE_KERNELS"):
        kernels.mode()
    with kernels.forced("auto"):
        assert kernels.mode() == "auto"
    with pytest.raises(ValueError, match="mode must be"):
        kernels.forced("fortran").__enter__()


def test_a_forced_mode_pins_whether_the_kernels_run(monkeypatch: pytest.MonkeyPatch) -> None:
    """:func:`kernels.enabled` answers from the forced mode (pinned once per step), nested
    blocks included, and the environment's answer comes back after them."""
    require_numba()
    monkeypatch.setenv(kernels.ENV, "auto")
    assert kernels.enabled()
    with kernels.forced("numpy"):
        assert not kernels.enabled()
        monkeypatch.setenv(kernels.ENV, "auto")  # pinned: the environment is not read
        assert not kernels.enabled()
        with kernels.forced("numba"):
            assert kernels.enabled()
        assert not kernels.enabled()
    assert kernels.enabled()
    monkeypatch.setenv(kernels.ENV, "numpy")
    assert not kernels.enabled()


def test_warm_up_compiles_every_kernel(numba_kernels: None) -> None:
    from skelfuse.fusion import kernels_rom

    assert kernels.warm_up() > 0.0
    # Strided, read-only inputs reuse the warm-up's compilation (none mid-stream).
    views = _views(0)[::2]
    views.flags.writeable = False
    assert anatomy.rom_factors_and_forward(views, 15.0)[0].shape == (len(views), 25)
    assert len(kernels_rom.rom_loop.signatures) == 1  # type: ignore[attr-defined]


@pytest.mark.parametrize("mode", ["numpy", "numba"])
@pytest.mark.parametrize("config", sorted(golden.DIGESTS))
def test_golden_replay_on_each_path(mode: str, config: str, tmp_path: Path) -> None:
    """test_golden_replay.py's digests, with the kernels forced on and forced off."""
    if mode == "numba":
        require_numba()
    with kernels.forced(mode):
        golden.test_replay_output_is_byte_identical_to_the_golden_digest(config, tmp_path)


def test_without_numba_everything_runs_on_numpy(monkeypatch: pytest.MonkeyPatch) -> None:
    """As the server's wheel and Docker image run: numba not importable."""
    from skelfuse import jit as shared_jit
    from skelfuse.fusion import kernels_jit

    monkeypatch.setitem(sys.modules, "numba", None)  # import numba raises ImportError
    monkeypatch.setattr(shared_jit, "_found", {})  # the lookup is skelfuse.jit's, below both
    assert kernels_jit.numba_module() is None
    assert not kernels.enabled() and kernels.warm_up() == 0.0

    def loop(x: float) -> float:
        return x

    assert kernels_jit.jit(loop) is loop
    views = _views(1)[:6]
    factors, _ = anatomy.rom_factors_and_forward(views, 15.0)
    assert factors.shape == (6, 25)


@pytest.mark.parametrize("seed", range(5))
def test_weighted_mean_kernel_gives_the_numpy_bits(numba_kernels: None, seed: int) -> None:
    rng = np.random.default_rng(seed)
    joints = _views(seed)[:48].reshape(6, 8, 25, 3)
    joints[0, :, 3] = -0.0  # a sum of negative zeros is +0 in numpy's reduction
    weights = rng.uniform(-0.2, 1.0, joints.shape[:3])  # some negative: they count as 0
    weights[rng.random(weights.shape) < 0.2] = 0.0
    weights[1, :, :5] = 0.0  # joints no view carries: NaN
    weights[2, 0, 7] = np.nan
    for size in (8, 3, 1):
        fused = weighted.weighted_mean(joints[:, :size], weights[:, :size])
        with kernels.forced("numpy"):
            expected = weighted.weighted_mean(joints[:, :size], weights[:, :size])
        assert _same_bits(fused, expected)
        assert np.isnan(fused).any()


def test_a_forced_mode_holds_in_its_own_thread_only(monkeypatch: pytest.MonkeyPatch) -> None:
    """A live server fuses (and forces its mode) in its own thread: it must not change the mode
    another thread sees, nor leave its mode behind when steps overlap."""
    import threading

    monkeypatch.setenv(kernels.ENV, "numpy")
    inside, release = threading.Event(), threading.Event()

    def step() -> None:
        with kernels.forced("auto"):
            inside.set()
            release.wait(5)

    worker = threading.Thread(target=step)
    worker.start()
    assert inside.wait(5)
    try:
        assert kernels.mode() == "numpy" and not kernels.enabled()
    finally:
        release.set()
        worker.join(5)
    assert kernels.mode() == "numpy" and not kernels.enabled()


def test_plain_gives_kernels_writable_arrays_and_copies_a_table_once() -> None:
    from skelfuse.fusion.kernels_jit import plain

    writable = np.arange(6.0)
    assert plain(writable) is writable  # as it is
    table = np.arange(6)
    table.flags.writeable = False  # a shared index table: owns its data, never changes
    copy = plain(table, np.intp)
    assert copy is not table and copy.flags.writeable and np.array_equal(copy, table)
    assert plain(table, np.intp) is copy  # kept: copied once
    base = np.arange(4.0)
    view = np.broadcast_to(base, (2, 4))  # read-only, over data that may change
    assert np.array_equal(plain(view), [[0, 1, 2, 3]] * 2)
    base[0] = 9.0
    assert plain(view)[1, 0] == 9.0  # a view is copied afresh every time
    ints = plain([1, 2], np.float64)
    assert ints.dtype == np.float64 and ints.flags.writeable and ints.flags.c_contiguous
