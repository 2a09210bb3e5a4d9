"""The house reads like the data flow: small modules, and docs that point to files that exist.

- No library or benchmark module over 400 lines (data tables excepted, listed by name).
- Every file path the README and docs/ name in backticks exists.
- Every cross-reference in a docstring or a doc (``:mod:`skelfuse.fusion.pipeline```,
  ``:func:`fusion.weighted.weighted_mean```...) names a module, and a name in it, that exist.
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
LAYERS = ("geometry", "protocol", "agent", "calibration", "fusion", "recording", "server")
SOURCE_FOLDERS = (*LAYERS, "skelfuse", "bench")
MAX_LINES = 400
DATA_TABLES: frozenset[str] = frozenset()
"""Modules allowed past the limit because they are data, not logic (none today)."""

DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
_FOLDERS = "|".join((*SOURCE_FOLDERS, "docs", "tests", "scripts"))
PATH_IN_BACKTICKS = re.compile(rf"`((?:{_FOLDERS})/[\w/.-]+\.\w+)`")
REFERENCE = re.compile(
    rf":(?:mod|func|class|data|meth|attr):`~?((?:skelfuse\.)?(?:{'|'.join(LAYERS)})\.[\w.]+)`"
)


def _sources() -> list[Path]:
    return sorted(
        path
        for folder in SOURCE_FOLDERS
        for path in (ROOT / folder).rglob("*.py")
        if "static" not in path.parts
    )


def test_no_module_is_over_the_size_limit() -> None:
    too_long = {
        str(path.relative_to(ROOT)): count
        for path in _sources()
        if (count := len(path.read_text(encoding="utf-8").splitlines())) > MAX_LINES
        and str(path.relative_to(ROOT)) not in DATA_TABLES
    }
    assert not too_long, f"split these by concept (limit {MAX_LINES} lines): {too_long}"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_paths_named_in_the_docs_exist(doc: Path) -> None:
    missing = sorted(
        {m for m in PATH_IN_BACKTICKS.findall(doc.read_text(encoding="utf-8"))
         if not (ROOT / m).exists()}
    )  # fmt: skip
    assert not missing, f"{doc.name} names files that do not exist: {missing}"


def _resolves(reference: str) -> bool:
    """Whether ``[skelfuse.]layer.module[.name[.attr]]`` names something that exists."""
    dotted = reference if reference.startswith("skelfuse.") else f"skelfuse.{reference}"
    parts = dotted.split(".")
    for split in range(len(parts), 1, -1):
        try:
            target: object = importlib.import_module(".".join(parts[:split]))
        except ModuleNotFoundError:
            continue
        for name in parts[split:]:
            if not hasattr(target, name):
                annotations = getattr(target, "__annotations__", {})
                fields = getattr(target, "__dataclass_fields__", {})
                # else an attribute declared in a class body or a dataclass field
                return name in annotations or name in fields
            target = getattr(target, name)
        return True
    return False


def test_cross_references_name_things_that_exist() -> None:
    texts = {str(p.relative_to(ROOT)): p.read_text(encoding="utf-8") for p in _sources() + DOCS}
    broken = sorted(
        f"{where}: {ref}"
        for where, text in texts.items()
        for ref in set(REFERENCE.findall(text))
        if not _resolves(ref.rstrip("."))
    )
    assert not broken, "stale references:\n" + "\n".join(broken)
