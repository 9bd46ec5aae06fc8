"""The layout README.md describes holds: what each package may import, and modules of one job each.

Every ``import`` statement of every module (those inside functions too) is read with :mod:`ast`, so a lazy import
that crosses a boundary fails here as surely as one at the top of a file.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: What each part of kmpipe may import from kmpipe besides itself (``kmpipe`` alone: ``__version__``).
ALLOWED = {
    "physics": {"errors", "formats"},  # physics reads certificates and CSVs through formats
    "formats": {"errors", "physics"},
    "validation": {"errors", "physics", "formats"},
    "stages": {"errors", "physics", "formats", "validation"},
    "run": {"errors", "physics", "formats", "validation", "stages"},
}
#: Modules longer than the ~500 lines a module of one job takes, and why.
LONG_MODULES = {
    "instruments/cs2000/protocol.py": "the CS-2000's whole command set, a table and a parser per command",
    "kmpipe/cli.py": "the argparse definitions of eleven commands, each option with its help",
}
MAX_LINES = 530


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in the file, relative imports resolved."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{parent}.{base}" if base else parent
            found.append((node.lineno, base))
            if base == "kmpipe":  # from kmpipe import x: x is a part of kmpipe
                found += [(node.lineno, f"kmpipe.{alias.name}") for alias in node.names]
    return found


def modules(*folders: str) -> list[Path]:
    return sorted(p for folder in folders for p in (ROOT / folder).rglob("*.py") if "__pycache__" not in p.parts)


@pytest.mark.parametrize("leaf", ["instruments", "renderer"])
def test_the_leaves_never_import_kmpipe(leaf):
    crossing = [
        f"{path.relative_to(ROOT)}:{line} imports {name}"
        for path in modules(leaf)
        for line, name in imported_modules(path)
        if name == "kmpipe" or name.startswith("kmpipe.")
    ]
    assert not crossing, "\n".join(crossing)


@pytest.mark.parametrize("part", sorted(ALLOWED))
def test_each_part_of_kmpipe_imports_only_what_the_layout_allows(part):
    crossing = []
    for path in modules(f"kmpipe/{part}"):
        for line, name in imported_modules(path):
            pieces = name.split(".")
            if pieces[0] != "kmpipe" or len(pieces) == 1 or pieces[1] in (part, "__version__"):
                continue
            if pieces[1] not in ALLOWED[part]:
                crossing.append(f"{path.relative_to(ROOT)}:{line} imports {name}")
    assert not crossing, "\n".join(crossing)


def test_the_layout_rule_itself_is_a_ladder():
    """Each part may use only parts before it (physics and formats lean on each other for files only)."""
    order = ["physics", "formats", "validation", "stages", "run"]
    for i, part in enumerate(order):
        assert ALLOWED[part] - {"errors"} <= set(order[:i]) | ({"formats"} if part == "physics" else set())


def test_modules_do_one_job_each_by_size():
    long = {}
    for path in modules("kmpipe", "instruments", "renderer"):
        name = path.relative_to(ROOT).as_posix()
        lines = path.read_text(encoding="utf-8").count("\n")
        if lines > MAX_LINES and name not in LONG_MODULES:
            long[name] = lines
    assert not long, f"modules over {MAX_LINES} lines without a stated reason: {long}"
    for name in LONG_MODULES:
        assert (ROOT / name).is_file(), f"{name} is listed as long but does not exist"
