"""The house reads like the data flow: short functions, and docs that point to files that exist.

- No library or benchmark function over 80 lines, ``def`` to its last line, docstring included
  (nested functions count on their own); the few longer ones are listed, each with its reason.
- No module over 800 lines: a concept owns its module, and one that long holds several.
- Every file path the README and docs/ name in backticks exists.
- Every cross-reference in a docstring or a doc (``:mod:`skelfuse.fusion.pipeline```,
  ``:func:`fusion.weigh.weighted_mean```...) names a module, and a name in it, that exist.
"""

from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
LAYERS = ("geometry", "protocol", "agent", "calibration", "fusion", "recording", "server")
SOURCE_FOLDERS = (*LAYERS, "skelfuse", "bench")
MAX_FUNCTION_LINES = 80
MAX_MODULE_LINES = 800
LONG_FUNCTIONS: dict[str, str] = {
    "agent/reproject_raster.py::raster_loop": "a numba kernel: one loop nest over the mesh's "
    "blocks, whose six triangle cases share a dozen scalars a helper would take as arguments",
}
"""``path::qualname`` of the functions allowed past :data:`MAX_FUNCTION_LINES`, with why."""

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


def _function_lengths(path: Path) -> dict[str, int]:
    """``qualname`` → lines from ``def`` to the last line, for every function and method of the
    module at ``path``, nested ones too (``outer.<locals>.inner``, as Python names them)."""
    lengths: dict[str, int] = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                qualname = prefix + child.name
                assert child.end_lineno is not None
                lengths[qualname] = child.end_lineno - child.lineno + 1
                visit(child, qualname + ".<locals>.")
            elif isinstance(child, ast.ClassDef):
                visit(child, prefix + child.name + ".")
            else:
                visit(child, prefix)

    visit(ast.parse(path.read_text(encoding="utf-8")), "")
    return lengths


def _all_function_lengths() -> dict[str, int]:
    return {
        f"{path.relative_to(ROOT)}::{qualname}": count
        for path in _sources()
        for qualname, count in _function_lengths(path).items()
    }


def test_function_lengths_are_measured_from_def_to_last_line(tmp_path: Path) -> None:
    module = tmp_path / "m.py"
    module.write_text(
        "class C:\n    def method(self):\n        pass\n\n\n"
        "def outer():\n    def inner():\n        return 1\n\n    return inner\n",
        encoding="utf-8",
    )
    assert _function_lengths(module) == {"C.method": 2, "outer": 5, "outer.<locals>.inner": 2}


def test_no_function_is_over_the_length_limit() -> None:
    too_long = {
        name: count
        for name, count in _all_function_lengths().items()
        if count > MAX_FUNCTION_LINES and name not in LONG_FUNCTIONS
    }
    assert not too_long, (
        f"split these at their concepts (limit {MAX_FUNCTION_LINES} lines), or list one in "
        f"LONG_FUNCTIONS with the reason it must stay whole: {too_long}"
    )


def test_every_long_function_listed_is_still_long() -> None:
    lengths = _all_function_lengths()
    stale = sorted(name for name in LONG_FUNCTIONS if lengths.get(name, 0) <= MAX_FUNCTION_LINES)
    assert not stale, f"gone or short now: take them out of LONG_FUNCTIONS: {stale}"
    assert all(reason.strip() for reason in LONG_FUNCTIONS.values())


def test_no_module_is_over_the_size_limit() -> None:
    too_long = {
        str(path.relative_to(ROOT)): count
        for path in _sources()
        if (count := len(path.read_text(encoding="utf-8").splitlines())) > MAX_MODULE_LINES
    }
    assert not too_long, f"split these by concept (limit {MAX_MODULE_LINES} lines): {too_long}"


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
