"""``skelfuse doctor``: which sensor sources can run on this PC, and why not."""

from __future__ import annotations

import argparse
import sys


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``doctor`` to the command line."""
    doctor = sub.add_parser("doctor", help="which sensor sources can run on this PC")
    doctor.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Print Python, platform and one line per source kind; always 0."""
    from skelfuse.agent.sources.registry import check_sources

    bits = 64 if sys.maxsize > 2**32 else 32
    lines = [f"Python {sys.version.split()[0]} ({bits}-bit) on {sys.platform}"]
    for check in check_sources():
        mark = "yes" if check.available else "no "
        lines.append(f"  {check.kind:13s} {mark}  {check.reason}")
    lines.extend(_pose_source_lines())
    sys.stdout.write("\n".join(lines) + "\n")
    return 0


def _pose_source_lines() -> list[str]:
    """The pose sources of a moving sensor (``--pose-source``; docs/sensors.md)."""
    from skelfuse.agent.poses.openvr_source import check_openvr

    available, reason = check_openvr()
    return [
        "pose sources (--pose-source, moving sensors):",
        "  file          yes  built in: a pose file (CSV or JSON lines)",
        f"  openvr        {'yes' if available else 'no '}  {reason}",
    ]
