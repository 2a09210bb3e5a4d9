"""Run a command on a pseudo-terminal, as a person runs it, with its output copied to a file.

The demo shows the viewer's whole address (with the token) only when its output is a terminal
(``skelfuse.demo.viewer_box``); tests that read what a person sees run it here.
"""

from __future__ import annotations

import os
import pty
import re
import subprocess
import threading
import tty
from pathlib import Path
from typing import Any

BOX_RULE = re.compile(r"^\+-+\+$")


def popen_in_terminal(command: list[str], log_path: Path, **kwargs: Any) -> subprocess.Popen[bytes]:
    """Start ``command`` with stdout and stderr on a new pseudo-terminal; a thread copies all
    it writes to ``log_path`` (until every process holding the terminal has exited).

    The terminal is raw (no ``\\r`` added), so the file reads as the lines written.
    """
    controller, terminal = pty.openpty()
    tty.setraw(terminal)
    try:
        process = subprocess.Popen(
            command, stdin=subprocess.DEVNULL, stdout=terminal, stderr=terminal, **kwargs
        )
    finally:
        os.close(terminal)

    def copy() -> None:
        with log_path.open("wb") as log:
            while True:
                try:
                    chunk = os.read(controller, 65536)
                except OSError:  # EIO: every holder of the terminal closed it
                    break
                if not chunk:
                    break
                log.write(chunk)
                log.flush()
        os.close(controller)

    threading.Thread(target=copy, name="terminal-copy", daemon=True).start()
    return process


def boxed_lines(text: str) -> list[list[str]]:
    """The contents of each ``+---+`` box in ``text``: its lines, without the borders."""
    boxes: list[list[str]] = []
    lines = text.splitlines()
    index = 0
    while index < len(lines):
        if BOX_RULE.match(lines[index]):
            end = index + 1
            while end < len(lines) and not BOX_RULE.match(lines[end]):
                end += 1
            if end < len(lines):
                boxes.append([line.strip("| ").rstrip() for line in lines[index + 1 : end]])
                index = end
        index += 1
    return boxes
