"""Rewrite reads of the flat ``FusionSettings`` fields of before into their groups.

``FusionSettings`` was 72 flat fields; it is now a few frozen groups (fusion/settings.py), and
``skelfuse.fusion.config.RENAMED`` records where each flat field went. This script is that
rename applied to code, and can be run again on a tree that gained old reads since (it is
idempotent: a second run changes nothing)::

    .venv/bin/python scripts/codemod_settings.py            # rewrite, then ruff the files
    .venv/bin/python scripts/codemod_settings.py --check    # list what it would change
    .venv/bin/python scripts/codemod_settings.py --no-ruff  # rewrite only

What it rewrites, in every ``.py`` file under fusion/ server/ recording/ skelfuse/ bench/
tests/ and the ``.toml`` files under tests/data:

- a read ``R.mirror_walk_check_s`` -> ``R.mirror.walk_check_s``. A field whose name is also an
  attribute of other objects (``filter``, ``alignment``, ``state_weights``, the ``facing_*`` of a
  sensor prior, ``enforce_bone_lengths`` the function) or kept its name inside its group
  (``rom_scale_deg``) is rewritten only on a settings receiver: ``s``, ``settings``,
  ``fusion``, ``SETTINGS``... (:data:`RECEIVERS`), a name the module assigns from
  ``FusionSettings(...)`` or ``replace(<settings>, ...)`` or annotates ``FusionSettings``;
- ``FusionSettings(mirror_redecide=False, filter="none")`` ->
  ``FusionSettings(mirror=MirrorSettings(redecide=False), smoothing=SmoothingSettings(
  filter="none"))``, importing the group classes;
- ``replace(s, mirror_redecide=False)`` -> ``replace(s, mirror=replace(s.mirror,
  redecide=False))`` (``dataclasses.replace`` too), and ``replace(FusionSettings(), ...)`` ->
  ``FusionSettings(...)``;
- a dict literal of flat keys handed to ``fusion_settings_from_mapping`` -> the nested dict;
- ````mirror_walk_check_s```` in docstrings and comments -> ````mirror.walk_check_s````;
- flat keys of a ``[fusion]`` table in a TOML file -> ``[fusion.<group>]`` tables.

It prints each file it changed and each line it could not rewrite (``**kwargs``, a removed
setting, a string key such as ``shown["use_facing"]``, an ambiguous read on an unknown
receiver): those are the hand work. Then, unless ``--no-ruff``, it runs ``ruff check --fix
--select I,F401`` and ``ruff format`` on the files it changed (import order, long lines).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import io
import re
import shutil
import subprocess
import sys
import tokenize
import typing
from pathlib import Path

from skelfuse.fusion.config import REMOVED, RENAMED
from skelfuse.fusion.settings import FusionSettings

ROOT = Path(__file__).resolve().parents[1]
LINE_LENGTH = 100
PY_DIRS = ("fusion", "server", "recording", "skelfuse", "bench", "tests")
TOML_DIR = "tests/data"
SKIP = {
    "fusion/config.py",  # the loader: reads the flat keys on purpose
    "scripts/codemod_settings.py",
    "tests/unit/test_fusion_config.py",  # tests the flat keys' deprecation on purpose
}

GROUP_CLASS: dict[str, str] = {
    f.name: typing.get_type_hints(FusionSettings)[f.name].__name__
    for f in dataclasses.fields(FusionSettings)
}
"""Group attribute -> its class name (``mirror`` -> ``MirrorSettings``)."""
NEW: dict[str, tuple[str, str]] = {
    old: (new.split(".")[0], new.split(".")[1]) for old, new in RENAMED.items()
}
AMBIGUOUS = {
    "filter",
    "alignment",
    "state_weights",
    "facing_power",
    "facing_floor",
    "facing_back_factor",
    "enforce_bone_lengths",
}
"""Old field names that are attributes of other objects too: rewritten on settings receivers."""
RECEIVERS = {"s", "settings", "_settings", "fusion", "fusion_settings", "SETTINGS"}
"""Names (the last part of a receiver) that hold a FusionSettings wherever they appear."""
NOT_SETTINGS = {
    *("self", "cls", "hub", "memory", "memories", "args", "r", "result", "out"),
    *("prior", "AZURE_BODY_TRACKING"),  # a sensor type's prior (fusion/priors.py)
}
"""Receivers of an ambiguous name known not to be settings: left alone without a report."""
SETTINGS_CALLS = {"FusionSettings", "fusion_settings_from_mapping", "load_fusion_settings"}


def last_name(node: ast.expr) -> str | None:
    """The last identifier of a receiver: ``hub.settings.fusion`` -> ``fusion``."""
    while isinstance(node, ast.Subscript):
        node = node.value
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return node.attr
    return None


def call_name(node: ast.expr) -> str | None:
    """``FusionSettings`` for ``FusionSettings(...)``, ``replace`` for ``dataclasses.replace``."""
    return last_name(node.func) if isinstance(node, ast.Call) else None


def _annotated(annotation: ast.expr) -> bool:
    """An annotation naming FusionSettings (``FusionSettings``, ``FusionSettings | None``)."""
    return "FusionSettings" in ast.unparse(annotation).replace("HubSettings", "")


def is_replace(node: ast.Call) -> bool:
    return call_name(node) == "replace" and len(node.args) == 1


class Source:
    """A module's text as UTF-8 bytes (ast's offsets), with edits applied at the end."""

    def __init__(self, text: str) -> None:
        self.data = text.encode("utf-8")
        self.starts = [0]
        for line in self.data.splitlines(keepends=True):
            self.starts.append(self.starts[-1] + len(line))
        self.edits: list[tuple[int, int, str]] = []

    def offset(self, line: int, col: int) -> int:
        return self.starts[line - 1] + col

    def span(self, node: ast.AST) -> tuple[int, int]:
        start = self.offset(node.lineno, node.col_offset)  # type: ignore[attr-defined]
        return start, self.offset(node.end_lineno, node.end_col_offset)  # type: ignore[attr-defined]

    def text(self, node: ast.AST) -> str:
        start, end = self.span(node)
        return self.data[start:end].decode("utf-8")

    def edit(self, start: int, end: int, new: str) -> None:
        if any(s < end and start < e for s, e, _ in self.edits):
            return  # nested in an edit of this pass: the next pass does it
        self.edits.append((start, end, new))

    def rewrap(self, start: int, end: int, new: str) -> None:
        """:meth:`edit` of a call, dropping a ``# fmt: skip`` after it: its hand layout is
        gone, ruff format lays the new call out."""
        rest = self.data[end:].split(b"\n", 1)[0]
        if rest.strip() == b"# fmt: skip":
            end += len(rest)
        self.edit(start, end, new)

    def result(self) -> str:
        data = self.data
        for start, end, new in sorted(self.edits, reverse=True):
            data = data[:start] + new.encode("utf-8") + data[end:]
        return data.decode("utf-8")


class Module:
    """One pass over one module: finds the rewrites, records the problems."""

    def __init__(self, path: str, text: str) -> None:
        self.path = path
        self.tree = ast.parse(text)
        self.src = Source(text)
        self.problems: list[str] = []
        self.imports: set[str] = set()
        self.receivers = RECEIVERS | self._inferred()
        self.parents = {
            child: node for node in ast.walk(self.tree) for child in ast.iter_child_nodes(node)
        }

    def problem(self, node: ast.AST, what: str) -> None:
        line = self.src.text(node).splitlines()[0] if hasattr(node, "lineno") else ""
        self.problems.append(f"{self.path}:{node.lineno}: {what}: {line.strip()[:100]}")  # type: ignore[attr-defined]

    def _inferred(self) -> set[str]:
        """Names this module assigns a FusionSettings to, or annotates as one."""
        names: set[str] = set()
        for _ in range(3):  # a name from replace(<a name found last round>, ...)
            for node in ast.walk(self.tree):
                targets: list[ast.expr] = []
                value: ast.expr | None = None
                if isinstance(node, ast.Assign):
                    targets, value = node.targets, node.value
                elif isinstance(node, ast.AnnAssign):
                    targets, value = [node.target], node.value
                    if _annotated(node.annotation):
                        names.add(last_name(node.target) or "")
                elif isinstance(node, ast.arg) and node.annotation is not None:
                    names.update([node.arg] if _annotated(node.annotation) else [])
                if value is not None and self._makes_settings(value, names):
                    names.update(n for t in targets if (n := last_name(t)))
        names.discard("")
        return names

    def _makes_settings(self, value: ast.expr, names: set[str]) -> bool:
        if not isinstance(value, ast.Call):
            return False
        name = call_name(value)
        if name in SETTINGS_CALLS:
            return True
        if name == "replace" and value.args:
            first = last_name(value.args[0])
            return first in RECEIVERS | names or call_name(value.args[0]) == "FusionSettings"
        return False

    def is_settings(self, node: ast.expr) -> bool:
        if call_name(node) == "FusionSettings":
            return True
        return last_name(node) in self.receivers

    # --- attribute reads ------------------------------------------------------------------
    def attribute(self, node: ast.Attribute) -> None:
        old = node.attr
        if old not in NEW and old not in REMOVED:
            return
        owner = last_name(node.value)
        if owner in GROUP_CLASS:
            return  # grouped already: s.weights.rom_scale_deg
        if old in REMOVED:
            if self.is_settings(node.value):
                self.problem(node, f"{old} was removed ({REMOVED[old]})")
            return
        group, new = NEW[old]
        needs_receiver = old in AMBIGUOUS or new == old
        if needs_receiver and not self.is_settings(node.value):
            if owner not in NOT_SETTINGS and not self._module_attribute(node):
                self.problem(node, f"left alone, not known as settings: .{old}")
            return
        if not needs_receiver and owner in NOT_SETTINGS:
            self.problem(node, f"left alone on {owner}: .{old}")
            return
        if old == "alignment" and self._grouped_alignment(node):
            return
        _, end = self.src.span(node)
        self.src.edit(end - len(old.encode()), end, f"{group}.{new}")

    def _module_attribute(self, node: ast.Attribute) -> bool:
        """``bones.enforce_bone_lengths``, ``fusion.alignment`` as a module: not settings."""
        return isinstance(self.parents.get(node), ast.Call) and self.parents[node].func is node  # type: ignore[attr-defined]

    def _grouped_alignment(self, node: ast.Attribute) -> bool:
        """``s.alignment.deadline_s`` or ``replace(s.alignment, ...)``: the group already, not
        the policy of before."""
        parent = self.parents.get(node)
        fields = {new for group, new in NEW.values() if group == "alignment"}
        if isinstance(parent, ast.Attribute) and parent.attr in fields:
            return True
        return isinstance(parent, ast.Call) and is_replace(parent) and parent.args[0] is node

    # --- keyword arguments ----------------------------------------------------------------
    def call(self, node: ast.Call) -> None:
        name = call_name(node)
        starred = any(k.arg is None for k in node.keywords)
        first = node.args[0] if node.args else node
        if starred and (
            name == "FusionSettings" or (name == "replace" and self.is_settings(first))
        ):
            self.problem(node, "settings from **kwargs: give the keys by group by hand")
        if name == "FusionSettings":
            self._constructor(node, node.args, node.keywords)
        elif name == "replace" and is_replace(node):
            self._replace(node)
        elif name == "fusion_settings_from_mapping" and isinstance(first, ast.Dict):
            self._mapping(first)

    def _old_keywords(self, keywords: list[ast.keyword], settings: bool) -> list[ast.keyword]:
        """The keywords naming flat fields of before (``settings``: the call makes settings)."""
        old = []
        for kw in keywords:
            if kw.arg is None or (kw.arg not in NEW and kw.arg not in REMOVED):
                continue
            if kw.arg in GROUP_CLASS and self._grouped_value(kw):
                continue  # alignment=AlignmentSettings(...): grouped already
            if settings or (kw.arg not in AMBIGUOUS and NEW.get(kw.arg, ("", kw.arg))[1] != kw.arg):
                old.append(kw)
        return old

    def _grouped_value(self, kw: ast.keyword) -> bool:
        value = kw.value
        if isinstance(value, ast.Constant):
            return False
        name = call_name(value)
        if name is not None and (name == "replace" or name.endswith("Settings")):
            return True
        self.problem(kw.value, f"ambiguous {kw.arg}= (old value or new group?), left alone")
        return True

    def _grouped(self, keywords: list[ast.keyword], base: str | None, func: str) -> str | None:
        """The keywords' text with the old ones grouped: ``mirror=MirrorSettings(...)`` or,
        with ``base`` (a replace's receiver), ``mirror=replace(base.mirror, ...)``."""
        old = self._old_keywords(keywords, True)
        for kw in old:
            if kw.arg in REMOVED:
                self.problem(kw, f"{kw.arg} was removed ({REMOVED[kw.arg]})")
                return None
        by_group: dict[str, list[str]] = {}
        for kw in old:
            group, new = NEW[kw.arg or ""]
            by_group.setdefault(group, []).append(f"{new}={self.src.text(kw.value)}")
        parts: list[str] = []
        for kw in keywords:
            if kw in old:
                continue
            text = self.src.text(kw.value)
            if kw.arg is None:
                parts.append(f"**{text}")
            elif kw.arg in by_group:  # mirror=... and mirror_x=... both: merge into the call
                inner = kw.value
                if not isinstance(inner, ast.Call):
                    self.problem(kw, f"{kw.arg}= and its old fields both given")
                    return None
                parts.append(f"{kw.arg}={self._extend(inner, by_group.pop(kw.arg))}")
            else:
                parts.append(f"{kw.arg}={text}")
        for group, items in by_group.items():
            if base is None:
                self.imports.add(GROUP_CLASS[group])
                parts.append(f"{group}={GROUP_CLASS[group]}({', '.join(items)})")
            else:
                parts.append(f"{group}={func}({base}.{group}, {', '.join(items)})")
        return ", ".join(parts)

    def _extend(self, call: ast.Call, items: list[str]) -> str:
        text = self.src.text(call)
        inside = text[text.index("(") + 1 : -1].strip().rstrip(",")
        return f"{text[: text.index('(')]}({', '.join([inside, *items] if inside else items)})"

    def _constructor(
        self, node: ast.Call, args: list[ast.expr], keywords: list[ast.keyword]
    ) -> None:
        if not self._old_keywords(keywords, True) or self._has_comments(node):
            return
        grouped = self._grouped(keywords, None, "")
        if grouped is None:
            return
        head = [self.src.text(a) for a in args]
        start, end = self.src.span(node)
        self.src.rewrap(start, end, f"{self.src.text(node.func)}({', '.join([*head, grouped])})")

    def _replace(self, node: ast.Call) -> None:
        receiver = node.args[0]
        if last_name(receiver) in GROUP_CLASS:
            return  # replace(s.mirror, ...): a group's own fields
        settings = self.is_settings(receiver)
        if not self._old_keywords(node.keywords, settings) or self._has_comments(node):
            return
        if call_name(receiver) == "FusionSettings" and isinstance(receiver, ast.Call):
            if receiver.args or receiver.keywords:
                self.problem(node, "replace(FusionSettings(...), ...): merge by hand")
                return
            self._constructor(node, [], node.keywords)
            start, end = self.src.span(node)
            if self.src.edits and self.src.edits[-1][0] == start:
                _, end, new = self.src.edits.pop()
                self.src.edits.append((start, end, "FusionSettings" + new[new.index("(") :]))
            return
        if not isinstance(receiver, ast.Name | ast.Attribute | ast.Subscript):
            self.problem(node, "replace(<expression>, ...): name the settings first")
            return
        if any(kw.arg is None for kw in node.keywords):
            self.problem(node, "replace(..., **kwargs) of flat fields: rewrite by hand")
        base = self.src.text(receiver)
        grouped = self._grouped(node.keywords, base, self.src.text(node.func))
        if grouped is not None:
            start, end = self.src.span(node)
            self.src.rewrap(start, end, f"{self.src.text(node.func)}({base}, {grouped})")

    def _has_comments(self, node: ast.AST) -> bool:
        text = self.src.text(node)
        try:
            tokens = list(tokenize.generate_tokens(io.StringIO(text).readline))
        except (tokenize.TokenError, SyntaxError):
            return False
        if any(t.type == tokenize.COMMENT for t in tokens):
            self.problem(node, "a call with comments inside: rewrite by hand")
            return True
        return False

    def _mapping(self, node: ast.Dict) -> None:
        keys = [k.value if isinstance(k, ast.Constant) else None for k in node.keys]
        if not keys or any(not isinstance(k, str) for k in keys):
            return
        if not any(k in NEW for k in keys):
            return
        if not all(k in NEW or k in GROUP_CLASS for k in keys):
            self.problem(node, "a mapping of flat keys mixed with others: rewrite by hand")
            return
        by_group: dict[str, list[str]] = {}
        for key, value in zip(keys, node.values, strict=True):
            text = self.src.text(value)
            if key in GROUP_CLASS and isinstance(value, ast.Dict):
                by_group.setdefault(str(key), []).append(text.strip()[1:-1].strip().rstrip(","))
            else:
                group, new = NEW[str(key)]
                by_group.setdefault(group, []).append(f"{new!r}: {text}".replace("'", '"'))
        inner = ", ".join(f'"{g}": {{{", ".join(items)}}}' for g, items in by_group.items())
        start, end = self.src.span(node)
        self.src.edit(start, end, "{" + inner + "}")

    # --- string keys, docstrings and comments ---------------------------------------------
    def subscript(self, node: ast.Subscript) -> None:
        key = node.slice
        if not isinstance(key, ast.Constant) or not isinstance(key.value, str):
            return
        inner = node.value
        after_fusion = isinstance(inner, ast.Subscript) and ast.unparse(inner.slice) == "'fusion'"
        parent = self.parents.get(node)
        if isinstance(parent, ast.Subscript) and isinstance(parent.slice, ast.Constant):
            return  # ["fusion"]["alignment"]["policy"]: grouped already
        shown = key.value not in AMBIGUOUS and key.value not in GROUP_CLASS
        if key.value in NEW and (shown or after_fusion):
            self.problem(node, f"string key {key.value!r}: now {RENAMED[key.value]}")

    def prose(self, text: str) -> str:
        """````old```` -> ````group.new```` in docstrings and comments, for the names that are
        no other identifier of this module (``rom_scale_deg`` may be a parameter's)."""
        identifiers = {n.id for n in ast.walk(self.tree) if isinstance(n, ast.Name)}
        identifiers |= {n.arg for n in ast.walk(self.tree) if isinstance(n, ast.arg)}
        identifiers |= {
            n.name for n in ast.walk(self.tree) if isinstance(n, ast.FunctionDef | ast.ClassDef)
        }

        def swap(match: re.Match[str]) -> str:
            prefix, old, rest = match.group(1) or "", match.group(2), match.group(3) or ""
            if old not in NEW or (not prefix and (old in AMBIGUOUS or old in identifiers)):
                return match.group(0)
            return f"``{prefix}{RENAMED[old]}{rest}``"

        return re.sub(r"``(FusionSettings\.)?([a-z_0-9]+)( = [^`]+)?``", swap, text)

    def run(self) -> str:
        for node in ast.walk(self.tree):
            if isinstance(node, ast.Attribute):
                self.attribute(node)
            elif isinstance(node, ast.Call):
                self.call(node)
            elif isinstance(node, ast.Subscript):
                self.subscript(node)
        text = self.src.result()
        return add_imports(text, self.imports) if self.imports else text


def rewrite_prose(module: Module, text: str) -> str:
    """The docstrings' and comments' mentions of old names in ``text`` rewritten."""
    tokens = tokenize.generate_tokens(io.StringIO(text).readline)
    lines = text.splitlines(keepends=True)
    edits: list[tuple[tuple[int, int], tuple[int, int], str]] = []
    for tok in tokens:
        if tok.type in (tokenize.STRING, tokenize.COMMENT) and "``" in tok.string:
            new = module.prose(tok.string)
            if new != tok.string:
                edits.append((tok.start, tok.end, new))
                widths = [len(line) for line in (lines[tok.start[0] - 1] + new).splitlines()]
                if max(widths) > LINE_LENGTH:
                    module.problems.append(f"{module.path}:{tok.start[0]}: rewrap the text")
    if not edits:
        return text
    starts = [0]
    for line in lines:
        starts.append(starts[-1] + len(line))
    out_text = text
    for (sl, sc), (el, ec), new in reversed(edits):
        out_text = out_text[: starts[sl - 1] + sc] + new + out_text[starts[el - 1] + ec :]
    return out_text


def add_imports(text: str, names: set[str]) -> str:
    """``names`` imported from skelfuse.fusion.settings at the module's top level."""
    tree = ast.parse(text)
    have = {
        alias.asname or alias.name
        for node in tree.body
        if isinstance(node, ast.ImportFrom)
        for alias in node.names
    }
    missing = sorted(names - have)
    if not missing:
        return text
    lines = text.splitlines(keepends=True)
    for node in tree.body:
        ours = isinstance(node, ast.ImportFrom) and node.module == "skelfuse.fusion.settings"
        if ours and node.lineno == node.end_lineno and "(" not in lines[node.lineno - 1]:
            line = lines[node.lineno - 1].rstrip("\n")
            lines[node.lineno - 1] = f"{line}, {', '.join(missing)}\n"
            return "".join(lines)
    imports = [n for n in tree.body if isinstance(n, ast.Import | ast.ImportFrom)]
    after = imports[-1].end_lineno if imports else 0
    lines.insert(after or 0, f"from skelfuse.fusion.settings import {', '.join(missing)}\n")
    return "".join(lines)


def rewrite_python(path: str, text: str) -> tuple[str, list[str]]:
    """``text`` rewritten (passes until nothing changes: nested calls), and the problems."""
    problems: list[str] = []
    for _ in range(6):
        module = Module(path, text)
        new = module.run()
        problems = module.problems
        if new == text:
            break
        text = new
    last = Module(path, text)
    text = rewrite_prose(last, text)
    return text, sorted(set(problems + last.problems))


_KEY = re.compile(r"^(\s*)([A-Za-z_0-9]+)(\s*=.*)$")


def rewrite_toml(path: str, text: str) -> tuple[str, list[str]]:
    """A ``[fusion]`` table's flat keys moved to ``[fusion.<group>]`` tables (its comments
    before the table kept, a key's own comment kept with it)."""
    lines = text.splitlines()
    problems: list[str] = []
    try:
        start = lines.index("[fusion]")
    except ValueError:
        return text, problems
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("[")), len(lines))
    by_group: dict[str, list[str]] = {}
    kept: list[str] = []
    for number, line in enumerate(lines[start + 1 : end], start + 2):
        match = _KEY.match(line)
        if match is None or match.group(2) not in NEW:
            if match is not None and match.group(2) in REMOVED:
                problems.append(f"{path}:{number}: {match.group(2)} was removed: {line}")
            kept.append(line)
            continue
        group, new = NEW[match.group(2)]
        by_group.setdefault(group, []).append(f"{match.group(1)}{new}{match.group(3)}")
    if not by_group:
        return text, problems
    body = [line for line in kept if line.strip()]
    out = lines[:start] + ([("[fusion]"), *body, ""] if body else [])
    for group, items in by_group.items():
        out += [f"[fusion.{group}]", *items, ""]
    out = out[:-1] + lines[end:]
    return "\n".join(out) + ("\n" if text.endswith("\n") else ""), problems


def files() -> list[Path]:
    found = [p for d in PY_DIRS for p in sorted((ROOT / d).rglob("*.py"))]
    found += sorted((ROOT / TOML_DIR).rglob("*.toml"))
    return [p for p in found if p.relative_to(ROOT).as_posix() not in SKIP]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="change nothing, list what would")
    parser.add_argument("--no-ruff", action="store_true", help="do not run ruff on the files")
    args = parser.parse_args()
    changed: list[Path] = []
    problems: list[str] = []
    for path in files():
        relative = path.relative_to(ROOT).as_posix()
        text = path.read_text(encoding="utf-8")
        rewrite = rewrite_toml if path.suffix == ".toml" else rewrite_python
        new, found = rewrite(relative, text)
        problems += found
        if new != text:
            changed.append(path)
            if not args.check:
                path.write_text(new, encoding="utf-8")
    for path in changed:
        print(f"{'would change' if args.check else 'changed'}: {path.relative_to(ROOT)}")
    for problem in problems:
        print(f"not rewritten: {problem}")
    python = [str(p) for p in changed if p.suffix == ".py"]
    ruff = shutil.which("ruff", path=str(Path(sys.executable).parent)) or shutil.which("ruff")
    if python and not args.check and not args.no_ruff and ruff:
        subprocess.run([ruff, "check", "--fix", "--select", "I,F401", "-q", *python], check=False)
        subprocess.run([ruff, "format", "-q", *python], check=False)
    print(f"{len(changed)} files {'to change' if args.check else 'changed'}, "
          f"{len(problems)} lines to do by hand")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
