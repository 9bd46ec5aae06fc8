"""Sample manifests (kmpipe.formats.manifest, kmpipe.formats.sample): every refusal names the file, the line and the
field.

Expected line numbers are found independently of the code under test: each broken manifest is made by
replacing one line of a known-good manifest, and the expected line is the one where the replacement text
sits in the new file. Errors reached through the command line must end with exit status 2 and a
one-paragraph message (no traceback) that names the file.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from kmpipe import cli
from kmpipe.errors import InputError
from kmpipe.formats.manifest import load_manifest, parse_thickness_mm

ROOT = Path(__file__).resolve().parents[1]
F1 = ROOT / "recipes" / "samples" / "F1"
KMPIPE = Path(sys.executable).with_name("kmpipe")

GOOD = """\
# a drawdown of a foundation, measured as radiance with a white standard
[sample]
name = "F1"
product = "Liquid foundation"
kind = "foundation"

[white]
file = "white.csv"
column = "baso4"
certified = "builtin:baso4"
dark = { file = "white.csv", column = "dark" }

[fit]
method = "lsq"
grid = "380:780:5"

[[backing]]
name = "black"
file = "backings.csv"
column = "black"

[[backing]]
name = "white"
file = "backings.csv"
column = "white"

[[masstone]]
file = "F1.csv"
column = "masstone"

[[film]]
file = "F1.csv"
column = "film_15um_over_black"
over = "black"
thickness = "15 um"

[[film]]
file = "F1.csv"
column = "film_15um_over_white"
over = "white"
thickness = "15 um"

[[film]]
file = "F1.csv"
column = "film_30um_over_black"
over = "black"
thickness = "30 um"

[[film]]
file = "F1.csv"
column = "film_30um_over_white"
over = "white"
thickness = "30 um"
"""


def line_of(text: str, needle: str, occurrence: int = 1) -> int:
    """1-based line number of the ``occurrence``-th line of ``text`` that contains ``needle``."""
    hits = [n for n, line in enumerate(text.splitlines(), 1) if needle in line]
    assert len(hits) >= occurrence, f"{needle!r} occurs {len(hits)} times"
    return hits[occurrence - 1]


def replace(text: str, old: str, new: str, occurrence: int = 1) -> str:
    """``text`` with the ``occurrence``-th appearance of ``old`` replaced by ``new``."""
    start = -1
    for _ in range(occurrence):
        start = text.index(old, start + 1)
    return text[:start] + new + text[start + len(old) :]


def refusal(tmp_path: Path, text: str, name: str = "manifest.toml") -> InputError:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    with pytest.raises(InputError) as caught:
        load_manifest(path)
    err = caught.value
    assert err.path == path
    assert str(path) in str(err)
    return err


def test_the_good_manifest_and_the_bundled_ones_load(tmp_path):
    path = tmp_path / "manifest.toml"
    path.write_text(GOOD, encoding="utf-8")
    manifest = load_manifest(path)
    assert manifest.sample.name == "F1"
    assert [b.name for b in manifest.backing] == ["black", "white"]
    assert [f.thickness_mm for f in manifest.film] == pytest.approx([0.015, 0.015, 0.03, 0.03], rel=1e-15)
    assert manifest.white.dark.column == "dark"
    for folder in sorted((ROOT / "recipes" / "samples").iterdir()):
        if (folder / "manifest.toml").is_file():
            assert load_manifest(folder / "manifest.toml").sample.name == folder.name


def test_defaults_of_optional_tables(tmp_path):
    text = GOOD.split("[white]")[0] + "[[backing]]" + GOOD.split("[[backing]]", 1)[1]
    path = tmp_path / "manifest.toml"
    path.write_text(text, encoding="utf-8")
    manifest = load_manifest(path)
    assert manifest.white is None
    assert manifest.fit.method == "lsq"
    assert manifest.fit.grid is None and manifest.fit.saunderson is None and manifest.fit.noise is None
    assert manifest.fit.smoothness == 0.0
    assert manifest.fit.opaque_tolerance == 1e-3


# --- thickness ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "mm"),
    [
        ("30 um", 0.03),
        ("30 µm", 0.03),  # U+00B5 micro sign
        ("30 μm", 0.03),  # U+03BC Greek small letter mu
        ("30um", 0.03),
        ("0.03 mm", 0.03),
        ("30000 nm", 0.03),
        ("3e1 um", 0.03),
        ("15 um", 0.015),
        ("2.5 mm", 2.5),
        ("500 nm", 0.0005),
    ],
)
def test_thickness_units(text, mm):
    assert parse_thickness_mm(text) == pytest.approx(mm, rel=1e-15)


def test_thickness_in_other_units_gives_the_same_film(tmp_path):
    for spelling in ("30 um", "30 µm", "0.03 mm", "30000 nm"):
        path = tmp_path / "manifest.toml"
        path.write_text(replace(GOOD, '"30 um"', f'"{spelling}"', 2), encoding="utf-8")
        assert load_manifest(path).film[3].thickness_mm == pytest.approx(0.03, rel=1e-15)


@pytest.mark.parametrize("bad", ["30", "30 furlongs", "-5 um", "0 um", "0 mm", "um", "30 UM", "thick"])
def test_bad_thickness(tmp_path, bad):
    text = replace(GOOD, '"30 um"', f'"{bad}"')
    err = refusal(tmp_path, text)
    assert err.field == "film[3].thickness"
    assert err.line == line_of(text, f'thickness = "{bad}"')
    assert bad in err.message
    with pytest.raises(ValueError):
        parse_thickness_mm(bad)


def test_thickness_given_as_a_number_without_unit(tmp_path):
    text = replace(GOOD, '"30 um"', "30")
    err = refusal(tmp_path, text)
    assert err.field == "film[3].thickness"
    assert err.line == line_of(text, "thickness = 30")


# --- TOML syntax and structure ------------------------------------------------------------------------


def test_toml_syntax_error_names_the_line(tmp_path):
    text = replace(GOOD, 'kind = "foundation"', 'kind = "foundation')  # unterminated string
    err = refusal(tmp_path, text)
    assert err.line == line_of(text, 'kind = "foundation')
    assert "TOML" in err.message


def test_duplicate_key_is_a_toml_error(tmp_path):
    text = replace(GOOD, 'kind = "foundation"', 'kind = "foundation"\nname = "F2"')
    err = refusal(tmp_path, text)
    assert err.line == line_of(text, 'name = "F2"')


def test_unknown_key_in_an_optional_place(tmp_path):
    text = replace(GOOD, "product =", "prodcut =")
    err = refusal(tmp_path, text)
    assert err.field == "sample.prodcut"
    assert err.line == line_of(text, "prodcut =")
    assert "unknown" in err.message


def test_unknown_key_in_fit_and_in_an_inline_table(tmp_path):
    text = replace(GOOD, "method =", "methd =")
    err = refusal(tmp_path, text)
    assert (err.field, err.line) == ("fit.methd", line_of(text, "methd ="))

    text = replace(GOOD, 'column = "dark"', 'colum = "dark"')
    err = refusal(tmp_path, text)
    assert err.field == "white.dark.colum"
    assert err.line == line_of(text, 'colum = "dark"')


def test_misspelt_required_key_is_reported_as_the_typo(tmp_path):
    """`thicknes` for `thickness`: the message must point at the misspelt key on its own line.

    Reporting only "thickness is required but missing" at the [[film]] header hides the real mistake.
    """
    text = replace(GOOD, 'thickness = "30 um"', 'thicknes = "30 um"')
    err = refusal(tmp_path, text)
    assert err.field == "film[3].thicknes"
    assert err.line == line_of(text, "thicknes =")
    assert "unknown" in err.message


def test_unknown_table(tmp_path):
    text = replace(GOOD, "[fit]", "[fitting]")
    err = refusal(tmp_path, text)
    assert err.field == "fitting"
    assert err.line == line_of(text, "[fitting]")


def test_missing_sample_name(tmp_path):
    text = replace(GOOD, 'name = "F1"\n', "")
    err = refusal(tmp_path, text)
    assert err.field == "sample.name"
    assert err.line == line_of(text, "[sample]")
    assert "required" in err.message


def test_empty_sample_name(tmp_path):
    text = replace(GOOD, 'name = "F1"', 'name = ""')
    err = refusal(tmp_path, text)
    assert err.field == "sample.name"
    assert err.line == line_of(text, 'name = ""')


def test_no_film_at_all(tmp_path):
    text = GOOD.split("[[film]]")[0]
    err = refusal(tmp_path, text)
    assert err.field == "film"
    assert "required" in err.message


def test_film_over_an_unknown_backing(tmp_path):
    text = replace(GOOD, 'over = "white"', 'over = "grey"')
    err = refusal(tmp_path, text)
    assert err.field == "film[2].over"
    assert err.line == line_of(text, 'over = "grey"')
    assert "'grey'" in err.message and "'black'" in err.message and "'white'" in err.message


def test_duplicate_backing_names(tmp_path):
    text = replace(GOOD, 'name = "white"', 'name = "black"')
    err = refusal(tmp_path, text)
    assert err.field == "backing[2].name"
    assert err.line == line_of(text, 'name = "black"', 2)
    assert "twice" in err.message


@pytest.mark.parametrize("method", ["magic", "LSQ", "black_white", ""])
def test_bad_fit_method(tmp_path, method):
    text = replace(GOOD, 'method = "lsq"', f'method = "{method}"')
    err = refusal(tmp_path, text)
    assert err.field == "fit.method"
    assert err.line == line_of(text, "method =")
    assert "two-constant" in err.message and "black-white" in err.message and "lsq" in err.message


@pytest.mark.parametrize("grid", ["780:380:5", "380:780:0", "380:780:-5", "380:780", "a:b:c", "400-700", "nan:780:5"])
def test_bad_grid(tmp_path, grid):
    text = replace(GOOD, 'grid = "380:780:5"', f'grid = "{grid}"')
    err = refusal(tmp_path, text)
    assert err.field == "fit.grid"
    assert err.line == line_of(text, "grid =")
    assert grid in err.message


def test_grid_that_is_not_a_whole_number_of_steps(tmp_path):
    """400:700:7 cannot be built (300 nm is not a multiple of 7 nm): refused by the manifest, with its line."""
    text = replace(GOOD, 'grid = "380:780:5"', 'grid = "400:700:7"')
    err = refusal(tmp_path, text)
    assert err.field == "fit.grid"
    assert err.line == line_of(text, "grid =")


@pytest.mark.parametrize("constants", ["[0.04, 1.0]", "[-0.1, 0.6]", "[1.0, 0.6]", "[0.04, 1.5]", "[0.04]"])
def test_saunderson_outside_unit_interval(tmp_path, constants):
    text = replace(GOOD, 'grid = "380:780:5"', f'grid = "380:780:5"\nsaunderson = {constants}')
    err = refusal(tmp_path, text)
    assert err.field.startswith("fit.saunderson")
    assert err.line == line_of(text, "saunderson =")


def test_saunderson_inside_unit_interval_is_accepted(tmp_path):
    path = tmp_path / "manifest.toml"
    path.write_text(replace(GOOD, 'grid = "380:780:5"', 'grid = "380:780:5"\nsaunderson = [0.0, 0.6]'))
    assert load_manifest(path).fit.saunderson == (0.0, 0.6)


@pytest.mark.parametrize(
    ("key", "value"), [("noise", "0"), ("noise", "-0.01"), ("smoothness", "-1"), ("opaque_tolerance", "0.7")]
)
def test_bad_numbers_in_fit(tmp_path, key, value):
    text = replace(GOOD, 'grid = "380:780:5"', f'grid = "380:780:5"\n{key} = {value}')
    err = refusal(tmp_path, text)
    assert err.field == f"fit.{key}"
    assert err.line == line_of(text, f"{key} =")


def test_manifest_that_does_not_exist(tmp_path):
    with pytest.raises(InputError) as caught:
        load_manifest(tmp_path / "nope.toml")
    assert caught.value.path == tmp_path / "nope.toml"


# --- through the command line -------------------------------------------------------------------------------


def sample_folder(tmp_path: Path, manifest: str = GOOD) -> Path:
    """A copy of the bundled sample F1 with ``manifest`` as its manifest.toml."""
    folder = tmp_path / "F1"
    folder.mkdir()
    for name in ("F1.csv", "backings.csv", "white.csv"):
        shutil.copy(F1 / name, folder / name)
    (folder / "manifest.toml").write_text(manifest, encoding="utf-8")
    return folder


def fit_cli(capsys, folder: Path, *extra: str) -> tuple[int, str]:
    status = cli.main(["fit", str(folder / "manifest.toml"), "-o", str(folder / "out.json"), *extra])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return status, err


def one_paragraph(message: str) -> str:
    body = message.strip()
    assert "\n\n" not in body
    return " ".join(body.split())


def edit_csv(path: Path, column: str, edit) -> None:
    """Apply ``edit(wavelength, value) -> value`` to one column of a spectral CSV, keeping everything else."""
    lines = path.read_text(encoding="utf-8").splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("wavelength_nm"))
    k = lines[header].split(",").index(column)
    for i in range(header + 1, len(lines)):
        cells = lines[i].split(",")
        cells[k] = repr(edit(float(cells[0]), float(cells[k])))
        lines[i] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def test_the_unchanged_copy_fits(tmp_path, capsys):
    folder = sample_folder(tmp_path)
    status, err = fit_cli(capsys, folder)
    assert status == 0, err
    assert (folder / "out.json").is_file()


def test_cli_toml_error_in_a_real_process(tmp_path):
    text = replace(GOOD, 'kind = "foundation"', 'kind = "foundation')
    folder = sample_folder(tmp_path, text)
    run = subprocess.run(
        [str(KMPIPE), "fit", str(folder / "manifest.toml"), "-o", str(folder / "out.json")],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert run.returncode == 2
    assert "Traceback" not in run.stderr
    message = one_paragraph(run.stderr)
    assert str(folder / "manifest.toml") in message
    assert f"line {line_of(text, 'kind =')}" in message
    assert not (folder / "out.json").exists()


@pytest.mark.parametrize(
    ("old", "new", "occurrence", "needle", "field"),
    [
        ('thickness = "30 um"', 'thickness = "30 furlongs"', 1, "furlongs", "film[3].thickness"),
        ('over = "white"', 'over = "grey"', 1, "grey", "film[2].over"),
        ('name = "white"', 'name = "black"', 1, 'name = "black"', "backing[2].name"),
        ('method = "lsq"', 'method = "magic"', 1, "magic", "fit.method"),
        ('product = "', 'prodcut = "', 1, "prodcut", "sample.prodcut"),
    ],
)
def test_cli_manifest_errors(tmp_path, capsys, old, new, occurrence, needle, field):
    text = replace(GOOD, old, new, occurrence)
    folder = sample_folder(tmp_path, text)
    status, err = fit_cli(capsys, folder)
    assert status == 2
    message = one_paragraph(err)
    assert str(folder / "manifest.toml") in message
    occurrences = 2 if needle == 'name = "black"' else 1
    assert f"line {line_of(text, needle, occurrences)}" in message
    assert field in message


def test_cli_missing_csv_file(tmp_path, capsys):
    """The manifest names a CSV that does not exist: exit 2, naming the manifest, its line and the file."""
    text = replace(GOOD, 'file = "backings.csv"', 'file = "backing.csv"')
    folder = sample_folder(tmp_path, text)
    status, err = fit_cli(capsys, folder)
    assert status == 2
    message = one_paragraph(err)
    assert "backing.csv" in message
    assert str(folder / "manifest.toml") in message
    assert "backing[1].file" in message
    # The line of `file = "backing.csv"` is known from the manifest text.
    assert f"line {line_of(text, 'backing.csv')}" in message


def test_cli_missing_column(tmp_path, capsys):
    text = replace(GOOD, 'column = "film_30um_over_white"', 'column = "film_30um_white"')
    folder = sample_folder(tmp_path, text)
    status, err = fit_cli(capsys, folder)
    assert status == 2
    message = one_paragraph(err)
    assert "film_30um_white" in message
    assert str(folder / "manifest.toml") in message
    assert "film[4].column" in message
    for column in (
        "masstone",
        "film_15um_over_black",
        "film_15um_over_white",
        "film_30um_over_black",
        "film_30um_over_white",
    ):
        assert column in message
    # The line of `column = "film_30um_white"` is known.
    assert f"line {line_of(text, 'film_30um_white')}" in message


def test_cli_csv_holds_reflectance_but_manifest_has_white(tmp_path, capsys):
    folder = sample_folder(tmp_path)
    backings = folder / "backings.csv"
    text = backings.read_text(encoding="utf-8")
    text = text.replace("# quantity: radiance", "# quantity: reflectance")
    text = text.replace("# units: W sr-1 m-2 nm-1", "# units: 1")
    backings.write_text(text, encoding="utf-8")
    status, err = fit_cli(capsys, folder)
    assert status == 2
    message = one_paragraph(err)
    assert str(backings) in message
    assert "reflectance" in message and "radiance" in message and "[white]" in message


def test_cli_csv_holds_radiance_but_manifest_has_no_white(tmp_path, capsys):
    text = GOOD.split("[white]")[0] + "[fit]" + GOOD.split("[fit]", 1)[1]
    folder = sample_folder(tmp_path, text)
    status, err = fit_cli(capsys, folder)
    assert status == 2
    message = one_paragraph(err)
    assert "backings.csv" in message
    assert "radiance" in message and "reflectance" in message and "[white]" in message


def test_cli_white_reading_zero_somewhere(tmp_path, capsys):
    """A white standard reading 0 at 500 nm: the message must name the white standard's file and where."""
    folder = sample_folder(tmp_path)
    edit_csv(folder / "white.csv", "baso4", lambda w, v: 0.0 if w == 500.0 else v)
    status, err = fit_cli(capsys, folder)
    assert status == 2
    message = one_paragraph(err)
    assert "0" in message and "white" in message
    assert str(folder / "white.csv") in message
    assert re.search(r"\b500(\.0)? ?nm", message)


def test_cli_white_reading_ten_times_too_low(tmp_path, capsys):
    """The whole white reading scaled down 10x: refused, naming the white standard's file."""
    folder = sample_folder(tmp_path)
    edit_csv(folder / "white.csv", "baso4", lambda w, v: v / 10.0)
    status, err = fit_cli(capsys, folder)
    assert status == 2
    message = one_paragraph(err)
    assert "white" in message
    assert str(folder / "white.csv") in message


def test_cli_reflectance_above_limit_after_normalization(tmp_path, capsys):
    """The white reading 10x too low over 600-640 nm only: reflectance there comes out ~8, above 1.5."""
    folder = sample_folder(tmp_path)
    edit_csv(folder / "white.csv", "baso4", lambda w, v: v / 10.0 if 600.0 <= w <= 640.0 else v)
    status, err = fit_cli(capsys, folder)
    assert status == 2
    message = one_paragraph(err)
    assert "1.5" in message
    assert "backings.csv" in message
    assert "600" in message
    assert not (folder / "out.json").exists()
