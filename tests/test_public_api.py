"""kmpipe's public API (``kmpipe.__all__``): every name resolves, documents itself with an example, and every
example in the API's docstrings runs (doctest) and gives what it says."""

from __future__ import annotations

import doctest
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

import kmpipe

PUBLIC = [name for name in kmpipe.__all__ if name != "__version__"]
ROOT = Path(kmpipe.__file__).resolve().parent
#: Every kmpipe module whose docstrings hold examples, and every module of a public name.
MODULES = sorted(
    {".".join(p.relative_to(ROOT.parent).with_suffix("").parts).removesuffix(".__init__")
     for p in ROOT.rglob("*.py") if ">>> " in p.read_text(encoding="utf-8")}
    | {kmpipe._PUBLIC[name] for name in PUBLIC}
)  # fmt: skip


@pytest.mark.parametrize("name", PUBLIC)
def test_every_public_name_resolves_to_a_documented_function_with_an_example(name):
    value = getattr(kmpipe, name)
    assert callable(value)
    assert value.__module__ == kmpipe._PUBLIC[name]  # defined where the table says, not re-exported
    examples = doctest.DocTestFinder(recurse=False).find(value, name, globs={})
    assert examples and examples[0].examples, f"{name} has no >>> example in its docstring"


@pytest.mark.parametrize("module", MODULES)
def test_the_examples_in_the_docstrings_run_and_give_what_they_say(module, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # an example that writes relative files writes them here
    result = doctest.testmod(importlib.import_module(module), optionflags=doctest.ELLIPSIS, report=True)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples in {module} failed (see above)"
    assert result.attempted > 0


def test_importing_kmpipe_loads_no_science_or_graphics_library():
    """The CLI starts by importing kmpipe: the public names must load on first use, not at import."""
    code = "import sys, kmpipe; print(sorted(m for m in ('colour', 'scipy', 'OpenGL', 'nlopt') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_the_command_line_starts_without_colour_science_or_opengl():
    """``kmpipe --help`` (and every command's parser) needs none of them: a command loads what its work needs."""
    libraries = "('colour', 'matplotlib', 'OpenGL', 'numba')"
    code = f"import sys, kmpipe.cli; print(sorted(m for m in {libraries} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
    done = subprocess.run([sys.executable, "-m", "kmpipe", "--help"], capture_output=True, text=True, check=True)
    assert "COMMAND" in done.stdout


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'fit_everything'"):
        kmpipe.fit_everything  # noqa: B018
