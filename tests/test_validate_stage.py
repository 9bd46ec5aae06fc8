"""The validate stage (kmpipe.stages.validate): one implementation behind ``kmpipe validate`` and ``kmpipe run``'s
validate and reports tasks, and the check registry the severities of findings come from."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from kmpipe import cli
from kmpipe.errors import InputError
from kmpipe.run.tasks import do_reports, do_validate
from kmpipe.stages.fit import fit_manifests
from kmpipe.stages.validate import find_materials, validate_materials, write_report
from kmpipe.validation.checks import CHECKS, finding
from kmpipe.validation.material import validate_material

SAMPLES = Path(__file__).resolve().parents[1] / "recipes" / "samples"


@pytest.fixture(scope="module")
def line(tmp_path_factory) -> Path:
    """F1 and L1 of the bundled samples fitted into one folder."""
    folder = tmp_path_factory.mktemp("line")
    fit_manifests([SAMPLES / "F1" / "manifest.toml", SAMPLES / "L1" / "manifest.toml"], folder)
    return folder


def read_json(path: Path):
    return json.loads(path.read_text(encoding="utf-8"))


# --- the registry -------------------------------------------------------------------------------------------


def test_a_finding_takes_its_severity_from_the_registry():
    for code, check in CHECKS.items():
        if check.severity in ("warn", "fail"):
            assert finding(code, "m").severity == check.severity
            with pytest.raises(ValueError):
                finding(code, "m", level="fail" if check.severity == "warn" else "warn")
        else:
            assert check.severity == "warn/fail"
            assert [finding(code, "m", level=level).severity for level in ("warn", "fail")] == ["warn", "fail"]
            with pytest.raises(ValueError):
                finding(code, "m")  # a graded check must say which level
    with pytest.raises(KeyError):
        finding("no_such_check", "m")


# --- one material, a folder ---------------------------------------------------------------------------------


def test_a_folder_is_validated_into_one_report_per_sample_and_an_index(line, tmp_path):
    result = validate_materials(line, illuminants=("D65", "A"), output=tmp_path / "reports")
    assert [p.name for p in result.materials] == ["F1.json", "L1.json"]
    assert [e.report.material.name for e in result.entries] == ["F1", "L1"]
    assert result.broken == () and result.index == tmp_path / "reports" / "index.html"
    for entry in result.entries:
        name = entry.report.material.name
        assert entry.page == tmp_path / "reports" / name / "report.html" and entry.page.is_file()
        assert entry.document == tmp_path / "reports" / name / "validation.json"
        assert read_json(entry.document)["sample"] == name
    summary = read_json(tmp_path / "reports" / "summary.json")
    assert sorted(row["report"] for row in summary) == ["F1/report.html", "L1/report.html"]


def test_an_unreadable_material_in_a_folder_is_collected_and_the_others_go_on(tmp_path):
    folder = tmp_path / "line"
    folder.mkdir()
    (folder / "A0.json").write_text('{"format": "kmpipe-material/1", "oops"', encoding="utf-8")
    (folder / "notes.json").write_text('{"format": "kmpipe-validation/1"}', encoding="utf-8")  # not a material
    assert [p.name for p in find_materials(folder)] == ["A0.json"]
    with pytest.raises(InputError, match="not valid JSON"):
        validate_materials(folder)  # the only material: its error is the command's
    fit_manifests([SAMPLES / "F1" / "manifest.toml"], folder / "F1.json")
    result = validate_materials(folder, output=tmp_path / "out")
    assert [b.path.name for b in result.broken] == ["A0.json"]
    assert "not valid JSON" in result.broken[0].error.message
    assert [e.report.material.name for e in result.entries] == ["F1"]
    assert result.index == tmp_path / "out" / "index.html"


def test_one_material_reports_into_its_output_or_beside_itself(line, tmp_path):
    result = validate_materials(line / "F1.json", output=tmp_path / "out")
    assert result.index is None and result.entries[0].page == tmp_path / "out" / "report.html"
    result = validate_materials(line / "L1.json")
    assert result.entries[0].page == line / "reports" / "L1" / "report.html"


@pytest.mark.parametrize(
    "options, named",
    [
        ({"manifest": SAMPLES / "F1" / "manifest.toml"}, "--manifest"),
        ({"illuminants": ()}, "--illuminant"),
        ({"overrides": {"delta_e_warn": 3.0}}, "delta_e_warn"),
    ],
)
def test_bad_arguments_are_refused_before_anything_is_written(line, tmp_path, options, named):
    with pytest.raises(InputError) as caught:
        validate_materials(line, output=tmp_path / "out", **options)
    assert caught.value.field == named
    assert not (tmp_path / "out").exists()


# --- kmpipe run's tasks go through the same functions -------------------------------------------------------


def test_the_run_task_writes_the_report_kmpipe_validate_writes(line, tmp_path, capsys):
    material = str(line / "F1.json")
    result = do_validate(material, str(tmp_path / "run"), ["D65", "A"], {"delta_e_warn": 0.5})
    status = cli.main(["validate", material, "--illuminant", "D65,A", "--delta-e-warn", "0.5", "-o", str(tmp_path)])
    capsys.readouterr()
    assert status == 0
    assert read_json(tmp_path / "run" / "validation.json") == read_json(tmp_path / "validation.json")
    document = read_json(tmp_path / "validation.json")
    assert result == {
        "verdict": document["verdict"],
        "reasons": document["reasons"],
        "worst_delta_e": document["worst_delta_e_2000"],
        "colour_radius": document["uncertainty"]["radius_delta_e_2000_95"],
    }


def test_the_run_task_never_writes_a_report_over_an_input(tmp_path):
    """A material named validation.json in the folder the report goes to: refused, as ``kmpipe validate`` does."""
    [(material, _)] = fit_manifests([SAMPLES / "F1" / "manifest.toml"], tmp_path / "validation.json")
    before = material.read_bytes()
    with pytest.raises(InputError, match="never writes over its inputs"):
        do_validate(str(material), str(tmp_path), ["D65"], {})
    assert material.read_bytes() == before and not (tmp_path / "report.html").exists()
    with pytest.raises(InputError, match="never writes over its inputs"):
        write_report(validate_material(material), tmp_path)


def test_the_run_index_is_the_folder_index(line, tmp_path):
    result = validate_materials(line, output=tmp_path)
    written = {name: (tmp_path / name).read_bytes() for name in ("index.html", "summary.json")}
    for name in written:
        (tmp_path / name).unlink()
    pairs = [(str(e.document), str(e.page)) for e in reversed(result.entries)]
    assert do_reports(pairs, str(tmp_path)) == {"index": str(tmp_path / "index.html")}
    assert {name: (tmp_path / name).read_bytes() for name in written} == written
