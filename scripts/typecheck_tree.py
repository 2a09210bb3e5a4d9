"""Make ``build/typecheck/skelfuse/``: links to the real folders under the one import name.

The layers live in top-level folders mapped to ``skelfuse.*`` by setuptools (pyproject.toml);
mypy cannot follow setuptools' editable import hook, so it reads this tree of links instead.
Its messages name the link paths (``build/typecheck/skelfuse/fusion/engine.py`` is
``fusion/engine.py``).
"""

from __future__ import annotations

import shutil
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    mapping = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"][
        "package-dir"
    ]
    tree = ROOT / "build" / "typecheck"
    shutil.rmtree(tree, ignore_errors=True)
    (tree / "skelfuse").mkdir(parents=True)
    for entry in (ROOT / "skelfuse").iterdir():
        (tree / "skelfuse" / entry.name).symlink_to(entry)
    for package, folder in mapping.items():
        if package != "skelfuse":
            (tree / Path(*package.split("."))).symlink_to(ROOT / folder)


if __name__ == "__main__":
    main()
