"""docs/equations.md stays true: every function and test it names exists, and every equation the code tags with
``thesis eq. N.M`` is in its table."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = (ROOT / "docs" / "equations.md").read_text(encoding="utf-8")
ROWS = [line for line in DOC.splitlines() if line.startswith("| ") and not line.startswith(("| eq.", "|---"))]


def _defines(path: Path, name: str) -> bool:
    """Whether ``path`` defines ``name`` (a function, class or constant; ``Class.method``; a GLSL function)."""
    text = path.read_text(encoding="utf-8")
    last = name.split(".")[-1]
    patterns = [
        rf"^\s*(?:def|class) {re.escape(last)}\b",
        rf"^\s*{re.escape(last)}\s*(?::[^=]+)?=",
    ]
    if path.suffix != ".py":  # a shader's function
        patterns.append(rf"\b{re.escape(last)}\s*\(")
    return any(re.search(p, text, re.M) for p in patterns)


def test_every_function_the_table_names_exists():
    missing = []
    for row in ROWS:
        for path, name in re.findall(r"`((?:kmpipe|renderer|instruments|tests)/[\w/.]+):([\w.]+)`", row):
            if not ((ROOT / path).is_file() and _defines(ROOT / path, name)):
                missing.append(f"{path}:{name}")
    assert not missing, missing


def test_every_test_the_table_names_exists():
    named = {(path, test) for row in ROWS for path, test in re.findall(r"`(tests/[\w/.]+)::(\w+)`", row)}
    assert len(named) > 20
    missing = [f"{p}::{t}" for p, t in sorted(named)
               if not re.search(rf"^def {t}\(", (ROOT / p).read_text(encoding="utf-8"), re.M)]  # fmt: skip
    assert not missing, missing


def test_every_tagged_equation_is_in_the_table():
    listed = set()
    for row in ROWS:
        cell = row.split("|")[1]
        listed |= set(re.findall(r"\b[A-Z]?\d*\.\d+\b", cell))
        for chapter, first, last in re.findall(r"\b([A-Z]|\d+)\.(\d+)-(?:[A-Z]|\d+)\.(\d+)\b", cell):  # A.1-A.3
            listed |= {f"{chapter}.{n}" for n in range(int(first), int(last) + 1)}
    tagged = {}
    for folder in ("kmpipe", "renderer", "instruments"):
        for path in (ROOT / folder).rglob("*"):
            if path.suffix in (".py", ".frag", ".vert", ".glsl") and "__pycache__" not in path.parts:
                for number in re.findall(r"thesis eq\. ([A-Z]?\d*\.\d+)", path.read_text(encoding="utf-8")):
                    tagged.setdefault(number, path.relative_to(ROOT).as_posix())
    assert len(tagged) >= 10
    assert not {n: p for n, p in tagged.items() if n not in listed}, "tagged in the code, missing from the table"


def test_tags_are_spelled_one_way():
    """``thesis eq. 3.8``: not ``eqs.``, ``Eq.``, ``equation 3.8`` or ``(3.8)`` alone."""
    odd = []
    for folder in ("kmpipe", "renderer", "instruments"):
        for path in (ROOT / folder).rglob("*"):
            if path.suffix in (".py", ".frag", ".vert", ".glsl") and "__pycache__" not in path.parts:
                text = path.read_text(encoding="utf-8")
                for match in re.finditer(r"thesis eqs\.|\bEqs?\. \d|thesis equation \d|\(eq\. \d", text):
                    odd.append(f"{path.relative_to(ROOT)}: {match.group(0)}")
    assert not odd, odd
