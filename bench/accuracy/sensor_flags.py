"""The command-line flags that choose the simulated sensors' error model (``--error-model``,
``--random-sensors``), shared by the accuracy benchmarks' parsers."""

from __future__ import annotations

import argparse

from skelfuse.agent.sim.sensor_units import ErrorModel


def add_error_model_flags(parser: argparse.ArgumentParser) -> None:
    """Add ``--error-model {kinect,tracker}`` and ``--random-sensors`` to ``parser``."""
    parser.add_argument(
        "--error-model",
        choices=("kinect", "tracker"),
        default="kinect",
        help="the simulated sensors' error model: the Kinect v2 model fusion was tuned on, "
        "or the depth body tracker (docs/simulator.md)",
    )
    parser.add_argument(
        "--random-sensors",
        action="store_true",
        help="every sensor a unit with parameters drawn from the run's seed "
        "(agent/sim/sensor_units.py)",
    )


def error_model_from(args: argparse.Namespace) -> ErrorModel:
    """The :class:`ErrorModel` the parsed flags ask for (the defaults: today's Kinect rig)."""
    return ErrorModel(kind=args.error_model, random_sensors=args.random_sensors)
