"""The filters' added latency at 30 Hz: lag on a ramp, rise on a step, noise left when still."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from bench.accuracy.runner import FPS
from skelfuse.fusion.filters import (
    ConstantVelocityKalman,
    DampedAccelerationKalman,
    JointFilter,
    OneEuroFilter,
)


def filter_latency() -> dict[str, dict[str, float]]:
    """Lag of each filter at 30 Hz on a 1 m/s ramp, 90 % rise time on a 10 cm step, and the
    residual of 10 mm white noise on a still joint (all per coordinate)."""
    dt = 1 / FPS
    made: dict[str, Callable[[], JointFilter]] = {
        "One Euro (min_cutoff 1.5 Hz, beta 10; the default before)": lambda: OneEuroFilter(
            1.5, 10.0, 1.0
        ),
        "Kalman CV (accel 8 m/s², meas 30 mm)": lambda: ConstantVelocityKalman(8.0, 0.03),
        "Kalman CV + 33 ms prediction": lambda: ConstantVelocityKalman(8.0, 0.03, 1 / 30),
        "Kalman CV + 12 ms lead (accel 5 m/s², proposed)": lambda: ConstantVelocityKalman(
            5.0, 0.03, 0.012
        ),
        "Kalman CA (default: jerk 3 + 30 per m/s, decay 0.1 s, 6 ms lead)": lambda: (
            DampedAccelerationKalman(3.0, 0.03, 0.1, 0.006, jerk_per_speed=30.0)
        ),
    }
    out: dict[str, dict[str, float]] = {}
    rng = np.random.default_rng(0)
    noise = rng.normal(0.0, 0.01, size=600)
    for label, make in made.items():
        ramp = make()
        lag = 0.0
        for n in range(120):
            y = float(ramp(np.array([n * dt * 1.0]), n * dt)[0])
            lag = (n * dt * 1.0 - y) / 1.0
        step = make()
        rise_ms = math.nan
        for n in range(120):
            y = float(step(np.array([0.0 if n < 10 else 0.1]), n * dt)[0])
            if n >= 10 and y >= 0.09 and math.isnan(rise_ms):
                rise_ms = (n - 10) * dt * 1000
        still = make()
        values = [float(still(np.array([noise[n]]), n * dt)[0]) for n in range(600)]
        out[label] = {
            "ramp_lag_ms": lag * 1000,
            "step_rise_90_ms": rise_ms,
            "noise_ratio": float(np.std(values[100:]) / np.std(noise[100:])),
        }
    return out
