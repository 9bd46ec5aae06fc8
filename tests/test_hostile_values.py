"""Hostile values in the files people hand kmpipe: every one is an InputError naming the file and the field (exit
status 2 on the command line), never an internal error (exit 70), a hang or an allocation of the machine's memory.

Materials (kmpipe.formats.material.read_material), sample manifests (kmpipe.formats.manifest.load_manifest),
validation configs
(kmpipe.formats.thresholds.Thresholds.from_toml) and card layouts
(kmpipe.formats.card_layout.load_card_layout, ``kmpipe card``).
Scenes and recipes are in test_render_scene.py, readings above 1 in test_fit.py.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kmpipe import cli
from kmpipe.errors import InputError
from kmpipe.formats.manifest import load_manifest
from kmpipe.formats.material import Material, MeasurementFit, material_to_dict, read_material, write_material
from kmpipe.formats.thresholds import Thresholds

WAVELENGTHS = np.array([400.0, 500.0, 600.0])


def material() -> Material:
    """A small valid material: three wavelengths, one masstone and one film."""
    return Material(
        name="M1",
        product="test",
        kind="foundation",
        wavelengths=WAVELENGTHS,
        channels=None,
        K=np.array([1.0, 2.0, 3.0]),
        S=np.array([50.0, 60.0, 70.0]),
        K_stderr=np.array([0.1, np.inf, 0.1]),
        S_stderr=np.array([1.0, np.inf, 1.0]),
        flags=np.array([0, 1, 0], dtype=np.uint8),
        method="lsq",
        saunderson=(0.04, 0.6),
        fit={"opaque_tolerance": 0.001},
        measurements=(
            MeasurementFit("r.csv:m", "masstone", None, np.inf, np.array([0.001, -0.002, 0.0])),
            MeasurementFit("r.csv:f", "film", "black", 0.02, np.array([0.0, 0.001, -0.001])),
        ),
        provenance={"manifest": "manifest.toml", "inputs": [{"path": "r.csv", "sha256": "0" * 64}]},
    )


@pytest.fixture
def document() -> dict:
    return material_to_dict(material())


def write_json(path: Path, doc) -> Path:
    path.write_text(json.dumps(doc), encoding="utf-8")
    return path


def refused(path: Path, field: str | None) -> InputError:
    with pytest.raises(InputError) as err:
        read_material(path)
    assert err.value.path == path
    assert err.value.field == field, str(err.value)
    return err.value


# --- materials ----------------------------------------------------------------------------------------------


def test_a_valid_material_reads_back_as_written(tmp_path):
    path = tmp_path / "M1.json"
    write_material(material(), path)
    back = read_material(path)
    assert np.array_equal(back.K, [1.0, 2.0, 3.0]) and np.array_equal(back.S, [50.0, 60.0, 70.0])
    assert np.isinf(back.K_stderr[1]) and back.flags.tolist() == [0, 1, 0]
    assert back.saunderson == (0.04, 0.6) and back.measurements[1].thickness_mm == 0.02


@pytest.mark.parametrize(
    ("edit", "field", "words"),
    [
        (lambda d: d.update(K=["NaN", 1.0, 2.0]), "K[1]", "expected a number"),
        (lambda d: d.update(K=[None, 1.0, 2.0]), "K[1]", "got null"),
        (lambda d: d.update(S=[1.0, -1.0, 2.0]), "S[2]", "[0, 1e+09]"),
        (lambda d: d.update(K=[1.0, 2.0, 1e300]), "K[3]", "finite number"),
        (lambda d: d.update(K=[1.0, 2.0]), "K", "a list of 3 numbers"),
        (lambda d: d.update(S={"a": 1}), "S", "a list of 3 numbers"),
        (lambda d: d.update(K=[True, 1.0, 2.0]), "K[1]", "a boolean"),
        (lambda d: d.update(name=7), "name", "expected text"),
        (lambda d: d.update(name="../../etc"), "name", "file name"),
        (lambda d: d.update(grid=[400, 500, 600]), "grid", "wavelengths_nm"),
        (lambda d: d.update(grid={"wavelengths_nm": [400, 500]}), "K", "a list of 2 numbers"),
        (lambda d: d.update(grid={"wavelengths_nm": [500, 400, 600]}), "grid.wavelengths_nm", "increasing"),
        (lambda d: d.update(flags=["opaque"]), "flags", "expected an object"),
        (lambda d: d.update(flags={"opaque": [450]}), "flags.opaque[1]", "not a wavelength"),
        (lambda d: d.update(flags={"opaque": [[400]]}), "flags.opaque[1]", "not a wavelength"),
        (lambda d: d.update(flags={"shiny": [400]}), "flags.shiny", "unknown flag"),
        (lambda d: d.update(saunderson={"k1": 0.04, "k2": 1.0}), "saunderson", "[0, 1)"),
        (lambda d: d.update(saunderson=[0.04, 0.6]), "saunderson", "expected an object"),
        (lambda d: d.update(measurements={"id": 1}), "measurements", "expected a list"),
        (lambda d: d["measurements"][1].update(residuals=[0, 0, "x"]), "measurements[2].residuals[3]", "number"),
        (lambda d: d["measurements"][1].update(thickness_mm=-1), "measurements[2].thickness_mm", "finite"),
        (lambda d: d["measurements"][0].update(role="film"), "measurements[1].thickness_mm", "masstone"),
        (lambda d: d["measurements"].append([]), "measurements[3]", "expected an object"),
        (lambda d: d.pop("method"), "method", "missing field"),
        (lambda d: d.update(provenance={"inputs": [{"path": 3, "sha256": "x"}]}), "provenance.inputs[1].path", "text"),
        (lambda d: d.update(K_stderr=[0.1, "inf", 0.1]), "K_stderr[2]", "expected a number"),
    ],
)
def test_a_broken_field_is_named(tmp_path, document, edit, field, words):
    edit(document)
    error = refused(write_json(tmp_path / "M.json", document), field)
    assert words in error.message


@pytest.mark.parametrize("constant", ["NaN", "Infinity", "-Infinity"])
def test_json_constants_that_are_not_numbers_are_refused(tmp_path, document, constant):
    text = json.dumps(document).replace('"K": [1.0', f'"K": [{constant}', 1)
    path = tmp_path / "M.json"
    path.write_text(text, encoding="utf-8")
    assert constant in refused(path, None).message


@pytest.mark.parametrize(
    "content",
    [
        bytes(range(256)) * 4,
        b"[" * 200_000 + b"]" * 200_000,
        b'{"format": "kmpipe-material/1", "grid": ' + b"[" * 100_000,
    ],
    ids=["random bytes", "deep nesting", "deep and unfinished"],
)
def test_bytes_that_are_not_a_material_are_refused(tmp_path, content):
    path = tmp_path / "M.json"
    path.write_bytes(content)
    refused(path, None)


def test_a_device_or_a_folder_is_not_read(tmp_path):
    with pytest.raises(InputError, match="not a regular file"):
        read_material("/dev/zero")
    with pytest.raises(InputError, match="is a folder"):
        read_material(tmp_path)


def test_a_non_finite_fit_result_is_refused_before_anything_is_written(tmp_path):
    broken = material()
    broken = Material(**{**broken.__dict__, "K": np.array([1.0, np.nan, 3.0])})
    path = tmp_path / "M.json"
    with pytest.raises(InputError) as err:
        write_material(broken, path)
    assert err.value.path == path and err.value.field == "K[2]"
    assert not path.exists() and list(tmp_path.iterdir()) == []


def test_validate_refuses_a_broken_material_with_exit_2(tmp_path, document, capsys):
    document["K"][0] = -1.0
    path = write_json(tmp_path / "M.json", document)
    assert cli.main(["validate", str(path), "-o", str(tmp_path / "out")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "M.json" in err and "'K[1]'" in err and "Traceback" not in err


JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False, allow_infinity=False) | st.text(max_size=8),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=6), children, max_size=4),
    max_leaves=12,
)
FIELDS = [
    *sorted(material_to_dict(material())),
    *("grid.wavelengths_nm", "measurements.0", "measurements.1.residuals", "saunderson.k1", "flags.opaque"),
    "provenance.inputs",
]


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(where=st.sampled_from(FIELDS), value=JSON_VALUES)
def test_any_json_value_in_any_field_reads_or_is_an_input_error(tmp_path, where, value):
    """Random JSON values in each field: the material reads (and then has finite K and S) or is an InputError
    naming the material file; never any other exception."""
    doc = copy.deepcopy(material_to_dict(material()))
    *parents, last = where.split(".")
    target = doc
    for key in parents:
        target = target[int(key)] if isinstance(target, list) else target[key]
    target[int(last) if isinstance(target, list) else last] = value
    path = write_json(tmp_path / "M.json", doc)
    try:
        read = read_material(path)
    except InputError as err:
        assert err.path == path
    else:
        assert np.all(np.isfinite(read.K)) and np.all(read.S >= 0.0)


# --- sample manifests ---------------------------------------------------------------------------------------

MANIFEST = """[sample]
name = "{name}"

[[backing]]
name = "black"
file = "cards.csv"
column = "black"

[[film]]
file = "films.csv"
column = "a"
over = "black"
thickness = "{thickness}"

[fit]
{fit}
"""


def manifest(tmp_path: Path, *, name="F1", thickness="20 um", fit="") -> Path:
    path = tmp_path / "manifest.toml"
    path.write_text(MANIFEST.format(name=name, thickness=thickness, fit=fit), encoding="utf-8")
    return path


@pytest.mark.parametrize("name", ["../../x", "/tmp/x", "a/b", "..", " F1", "a\\\\b"])
def test_a_sample_name_that_is_not_a_file_name_is_refused_with_its_line(tmp_path, name):
    path = manifest(tmp_path, name=name)
    with pytest.raises(InputError) as err:
        load_manifest(path)
    assert (err.value.path, err.value.field, err.value.line) == (path, "sample.name", 2)


@pytest.mark.parametrize(
    ("fit", "field"),
    [
        ("smoothness = inf", "fit.smoothness"),
        ("smoothness = nan", "fit.smoothness"),
        ("smoothness = 1e7", "fit.smoothness"),
        ("smoothness = -1", "fit.smoothness"),
        ("noise = 0.5", "fit.noise"),
        ("noise = nan", "fit.noise"),
        ("noise = 0", "fit.noise"),
        ("opaque_tolerance = inf", "fit.opaque_tolerance"),
        ("saunderson = [nan, 0.6]", "fit.saunderson"),
        ("saunderson = [0.04, inf]", "fit.saunderson"),
        ('grid = "0:700:5"', "fit.grid"),
        ('grid = "400:inf:5"', "fit.grid"),
    ],
)
def test_every_number_of_the_fit_table_is_finite_and_in_range(tmp_path, fit, field):
    path = manifest(tmp_path, fit=fit)
    with pytest.raises(InputError) as err:
        load_manifest(path)
    assert err.value.path == path and err.value.field.startswith(field) and err.value.line == 16


@pytest.mark.parametrize("thickness", ["1e999999999 mm", "101 mm", "inf um", "0 um", "-3 um", "nan mm"])
def test_a_film_thickness_is_positive_finite_and_at_most_100_mm(tmp_path, thickness):
    path = manifest(tmp_path, thickness=thickness)
    with pytest.raises(InputError) as err:
        load_manifest(path)
    assert (err.value.path, err.value.field, err.value.line) == (path, "film[1].thickness", 13)


def test_a_manifest_nested_too_deeply_or_on_a_device_is_refused(tmp_path):
    path = tmp_path / "deep.toml"
    path.write_text("a = " + "[" * 100_000, encoding="utf-8")
    with pytest.raises(InputError, match="nested too deeply") as err:
        load_manifest(path)
    assert err.value.path == path
    with pytest.raises(InputError, match="not a regular file"):
        load_manifest("/dev/zero")


def test_fit_refuses_an_escaping_sample_name_with_exit_2(tmp_path, capsys):
    path = manifest(tmp_path, name="../../outside")
    assert cli.main(["fit", str(path), "-o", str(tmp_path / "out.json")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "sample.name" in err and "manifest.toml" in err
    assert not (tmp_path / "out.json").exists()


# --- validation config --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "field"),
    [("[thresholds]\ndelta_e_warn = inf\n", "thresholds.delta_e_warn"),
     ("[thresholds]\nrmse_fail = nan\n", "thresholds.rmse_fail"),
     ("[thresholds]\nks_max = -1\n", "thresholds.ks_max")],
)  # fmt: skip
def test_a_threshold_is_a_positive_finite_number(tmp_path, text, field):
    path = tmp_path / "config.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(InputError) as err:
        Thresholds.from_toml(path)
    assert (err.value.path, err.value.field) == (path, field)


def test_a_validation_config_that_is_not_a_file_is_refused(tmp_path):
    with pytest.raises(InputError, match="is a folder") as err:
        Thresholds.from_toml(tmp_path)
    assert err.value.path == tmp_path


# --- card layouts -------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("key", "value"), [("width_mm", "1e9"), ("height_mm", "501"), ("width_mm", "nan")])
def test_kmpipe_card_refuses_a_card_larger_than_500_mm(tmp_path, capsys, key, value):
    from instruments.drawdown_card.layout import default_layout
    from kmpipe.formats.card_layout import write_card_layout

    layout = tmp_path / "card.toml"
    write_card_layout(default_layout(), layout)
    text = layout.read_text(encoding="utf-8")
    lines = [f"{key} = {value}" if line.startswith(f"{key} =") else line for line in text.splitlines()]
    layout.write_text("\n".join(lines) + "\n", encoding="utf-8")
    assert cli.main(["card", "--layout", str(layout), "-o", str(tmp_path / "card.png")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert f"card.{key}" in err and "card.toml" in err
    assert not (tmp_path / "card.png").exists()


def test_a_layout_on_a_device_is_not_read(tmp_path, capsys):
    assert cli.main(["card", "--layout", "/dev/zero", "-o", str(tmp_path / "card.png")]) == 2
    assert "not a regular file" in capsys.readouterr().err
