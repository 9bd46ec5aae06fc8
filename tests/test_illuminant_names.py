"""One illuminant resolver for every input (kmpipe.physics.colorimetry.illuminant_key): a scene, a recipe, the
validation command and an emulator script accept the same names (CIE ones, F for colour-science's FL series, LED)
and refuse the same bad ones, through the commands a user runs: exit status 2 naming the field.

Which names are known comes from colour-science's own table (``colour.SDS_ILLUMINANTS``), not from kmpipe.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import colour
import pytest

from kmpipe import cli
from kmpipe.errors import InputError
from kmpipe.formats.emulator_script import load_emulator_script
from kmpipe.stages.fit import fit_manifests

ROOT = Path(__file__).resolve().parents[1]
F1 = ROOT / "recipes" / "samples" / "F1"
#: Names a user may write and the colour-science illuminant each means; and names that mean none.
KNOWN = [("F11", "FL11"), ("fl2", "FL2"), ("LED-B3", "LED-B3"), ("d65", "D65")]
UNKNOWN = ["F99", "D6500", "sunlight"]


@pytest.fixture(scope="module")
def material(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("material") / "F1.json"
    fit_manifests([F1 / "manifest.toml"], path, method="black-white")
    return path


def _scene(folder: Path, material: Path, illuminant: str) -> Path:
    path = folder / "scene.toml"
    path.write_text(
        f'[scene]\nname = "card"\nilluminant = "{illuminant}"\nmesh = "card"\nresolution = [16, 16]\n'
        f'[substrate]\nreflectance = 0.8\n[[layer]]\nmaterial = "{material}"\nthickness = "20 um"\n'
        "[[light]]\ndirection = [0, 0, 1]\n"
    )
    return path


def _recipe(folder: Path, material: Path, line: str, validation: str) -> Path:
    shutil.copyfile(material, folder / "F1.json")
    path = folder / "recipe.toml"
    path.write_text(
        f'[line]\nname = "Line"\nilluminant = "{line}"\n[validation]\nilluminants = ["{validation}"]\n'
        '[scene]\nmesh = "card"\nresolution = [16, 16]\n[substrate]\nreflectance = 0.8\n'
        "[[light]]\ndirection = [0, 0, 1]\n"
        '[[product]]\nname = "F1"\nmaterial = "F1.json"\nlayer = [{ material = "self", thickness = "20 um" }]\n'
    )
    return path


def _emulator_script(folder: Path, illuminant: str) -> Path:
    for name in ("emulator.toml", "emulator_reflectance.csv"):
        shutil.copyfile(F1 / name, folder / name)
    path = folder / "emulator.toml"
    text = path.read_text()
    assert text.count('illuminant = "D55"') == 1
    path.write_text(text.replace('illuminant = "D55"', f'illuminant = "{illuminant}"'))
    return path


def _status(argv: list[str], capsys) -> tuple[int, str]:
    status = cli.main(argv)
    return status, capsys.readouterr().err


@pytest.mark.parametrize(("name", "key"), KNOWN)
def test_a_known_name_works_in_every_input(name, key, tmp_path, material, capsys):
    assert key in colour.SDS_ILLUMINANTS
    status, err = _status(["render", str(_scene(tmp_path, material, name)), "-o", str(tmp_path / "out")], capsys)
    assert status == 0, err
    recipe = _recipe(tmp_path, material, name, name)
    assert _status(["run", str(recipe), "-o", str(tmp_path / "line"), "--dry-run"], capsys)[0] == 0
    status, err = _status(["validate", str(material), "--illuminant", f"D65,{name}", "-o", str(tmp_path / "r")], capsys)
    assert status in (0, 1), err  # a verdict, not a refusal
    assert load_emulator_script(_emulator_script(tmp_path, name)) is not None


@pytest.mark.parametrize("name", UNKNOWN)
def test_an_unknown_name_is_refused_by_every_input_naming_the_field(name, tmp_path, material, capsys):
    assert name.upper() not in colour.SDS_ILLUMINANTS and f"FL{name[1:]}" not in colour.SDS_ILLUMINANTS
    status, err = _status(["render", str(_scene(tmp_path, material, name)), "-o", str(tmp_path / "out")], capsys)
    assert status == 2 and "scene.illuminant" in err and name in err
    for line, validation, field in ((name, "D65", "line.illuminant"), ("D65", name, "validation.illuminants")):
        recipe = _recipe(tmp_path, material, line, validation)
        status, err = _status(["run", str(recipe), "-o", str(tmp_path / "line"), "--dry-run"], capsys)
        assert status == 2 and field in err and name in err, err
    status, err = _status(["validate", str(material), "--illuminant", f"D65,{name}", "-o", str(tmp_path / "r")], capsys)
    assert status == 2 and "--illuminant" in err and name in err, err
    with pytest.raises(InputError) as refused:
        load_emulator_script(_emulator_script(tmp_path, name))
    assert refused.value.field == "samples.illuminant" and name in refused.value.message
    assert not (tmp_path / "out").exists() and not (tmp_path / "r").exists()  # nothing written
