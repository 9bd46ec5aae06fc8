"""The validate stage: fitted materials checked against their measurements, with reports (``kmpipe validate``, and
``kmpipe run``'s validate and reports tasks).

:func:`validate_materials` validates one MATERIAL.json or every material in a folder (a product line) and writes,
per sample, ``report.html`` and ``validation.json`` (:func:`write_report`), and for a folder the ``index.html`` and
``summary.json`` of its reports (:func:`index_reports`). What a validation checks: :mod:`kmpipe.validation`.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from kmpipe.errors import InputError
from kmpipe.formats import files
from kmpipe.formats.material import FORMAT as MATERIAL_FORMAT
from kmpipe.formats.thresholds import Thresholds
from kmpipe.validation.findings import SampleReport
from kmpipe.validation.material import validate_material
from kmpipe.validation.report import write_index, write_sample_report
from kmpipe.validation.uncertainty import DRAWS

#: Bytes at the start of a JSON file in which a material names its format.
_HEAD_BYTES = 4096


@dataclass(frozen=True)
class ReportWritten:
    """A validated sample and the files of its report."""

    report: SampleReport
    page: Path  # report.html
    document: Path  # validation.json


@dataclass(frozen=True)
class BrokenMaterial:
    """A material of a folder that could not be validated, and why."""

    path: Path
    error: InputError


@dataclass(frozen=True)
class Validated:
    """What :func:`validate_materials` did: the materials it found, the reports it wrote (in the materials' order),
    the materials it could not validate, and the index of a folder's reports (None for a single material, or when
    no report was written)."""

    materials: tuple[Path, ...]
    entries: tuple[ReportWritten, ...]
    broken: tuple[BrokenMaterial, ...]
    index: Path | None

    @property
    def failed(self) -> bool:
        """True when a validated sample's verdict is ``fail``."""
        return any(entry.report.verdict == "fail" for entry in self.entries)


def find_materials(target: str | Path) -> list[Path]:
    """``target`` itself when it is a file (a regular one, or InputError), or every material JSON directly inside a
    folder, by name: the ``*.json`` files whose first 4096 bytes name the material format (``"kmpipe-material/1"``),
    and any ``*.json`` that is not a regular file (to be reported as broken, not silently skipped). InputError for
    a folder holding none.

    >>> import tempfile, pathlib
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> _ = (folder / "F1.json").write_text('{"format": "kmpipe-material/1"}')
    >>> _ = (folder / "notes.json").write_text('{"format": "kmpipe-validation/1"}')
    >>> [path.name for path in find_materials(folder)]
    ['F1.json']
    """
    target = Path(target)
    if target.is_dir():
        found = []
        for path in sorted(target.glob("*.json")):
            try:
                head = files.read_head(path, _HEAD_BYTES)
            except InputError:
                found.append(path)  # not a regular file: reported as broken, the others go on
                continue
            if f'"{MATERIAL_FORMAT}"'.encode() in head:
                found.append(path)
        if not found:
            raise InputError(f'holds no kmpipe material files (*.json with "format": "{MATERIAL_FORMAT}")', path=target)
        return found
    files.regular_file(target, "material")
    return [target]


def write_report(report: SampleReport, folder: str | Path) -> ReportWritten:
    """Write ``report.html`` and then ``validation.json`` of ``report`` into ``folder`` (created), refusing (InputError
    naming ``-o``) to write over the material, its manifest or any file the material was fitted from.

    >>> import tempfile, pathlib, kmpipe
    >>> from kmpipe.stages.fit import fit_manifests
    >>> from kmpipe.validation.material import validate_material
    >>> F1 = pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "samples" / "F1"  # bundled example
    >>> manifest = F1 / "manifest.toml"
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> [(material, _)] = fit_manifests([manifest], folder / "validation.json")
    >>> report = validate_material(material)
    >>> written = write_report(report, folder / "report")
    >>> written.page.name, written.document.name, written.report.verdict
    ('report.html', 'validation.json', 'pass')
    >>> write_report(report, folder)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    kmpipe.errors.InputError: ...validation.json: field '-o': is also an input (...); kmpipe never writes over its...
    """
    folder = Path(folder)
    material = report.material_path
    inputs = [material, report.manifest_path, *(material.parent / i["path"] for i in report.material.provenance.get(
        "inputs", []))]  # fmt: skip
    for name in ("report.html", "validation.json"):
        files.refuse_inputs(folder / name, inputs)
    return ReportWritten(report, write_sample_report(report, folder), folder / "validation.json")


def index_reports(
    entries: Sequence[tuple[str | Path, str | Path]], out_dir: str | Path, links: Sequence[tuple[str, str]] = ()
) -> Path:
    """Write ``index.html`` and ``summary.json`` into ``out_dir`` over the reports given as (validation.json,
    report.html) pairs, failing samples first, with ``links`` (title, page) to other pages of the run (the shade
    review); return the index's path.

    >>> import tempfile, pathlib, json
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> document = {"sample": "F1", "product": "Foundation", "verdict": "warn", "worst_delta_e_2000": 0.5,
    ...             "reasons": ["opaque"]}
    >>> _ = (folder / "validation.json").write_text(json.dumps(document))
    >>> index = index_reports([(folder / "validation.json", folder / "report.html")], folder)
    >>> index.name, json.loads((folder / "summary.json").read_text())[0]["report"]
    ('index.html', 'report.html')
    """
    documents = [(json.loads(files.read_text(doc, "JSON")), Path(page)) for doc, page in entries]
    return write_index(documents, Path(out_dir), [(title, Path(page)) for title, page in links])


def _contexts(context: dict | None) -> list[dict] | None:
    """The command line's render context for one material: its defaults filled in from the sample when the other
    half is given (``--at`` alone: over the lightest backing; ``--over`` alone: the median film)."""
    if context is None:
        return None
    return [{**context, "base": str(Path.cwd()), "field": "--over"}]


def validate_materials(
    target: str | Path,
    *,
    manifest: str | Path | None = None,
    illuminants: Sequence[str] = ("D65",),
    observer: str = "2",
    config: str | Path | None = None,
    overrides: Mapping[str, float | None] | None = None,
    output: str | Path | None = None,
    context: dict | None = None,
    draws: int = DRAWS,
) -> Validated:
    """The validate stage: validate MATERIAL.json ``target``, or every material in folder ``target``
    (:func:`find_materials`), and write the reports (``kmpipe validate``).

    Thresholds: the defaults, or the ``[thresholds]`` table of TOML file ``config``, with ``overrides`` (threshold
    name -> value; None values are left out) on top. Delta E 2000 under each of ``illuminants`` for the CIE
    ``observer`` ("2" or "10"); ``manifest`` replaces the one a single material's provenance names. ``context``
    (``thickness_mm`` and ``over``, either None for its default) is where the rendered colour's doubt is judged, with
    ``draws`` Monte Carlo draws (:func:`kmpipe.validation.material.validate_material`).

    Reports go to ``output`` (default: ``reports/`` beside the material, or inside the folder): into ``SAMPLE/``
    under it for a folder's materials or when ``output`` is not given, else straight into ``output``; a folder's
    reports get an index there. A material of a folder that cannot be read or validated is collected in ``broken``
    and the others go on; a single one raises its InputError, as do bad arguments (a ``manifest`` with several
    materials, no illuminant, bad thresholds, an ``output`` that is not a folder) before anything is validated.

    >>> import tempfile, pathlib, kmpipe
    >>> from kmpipe.stages.fit import fit_manifests
    >>> samples = pathlib.Path(kmpipe.__file__).parents[1] / "recipes" / "samples"
    >>> line = pathlib.Path(tempfile.mkdtemp())
    >>> _ = fit_manifests([samples / "F1" / "manifest.toml", samples / "L1" / "manifest.toml"], line)
    >>> _ = (line / "X1.json").write_text('{"format": "kmpipe-material/1"}')
    >>> result = validate_materials(line, illuminants=("D65", "A"), overrides={"delta_e_warn": 1.5})
    >>> [(entry.report.material.name, entry.report.verdict) for entry in result.entries]
    [('F1', 'pass'), ('L1', 'pass')]
    >>> [(broken.path.name, type(broken.error).__name__) for broken in result.broken]
    [('X1.json', 'InputError')]
    >>> result.index.relative_to(line).as_posix(), result.entries[0].page.relative_to(line).as_posix()
    ('reports/index.html', 'reports/F1/report.html')
    >>> result.entries[0].report.thresholds.delta_e_warn, result.failed
    (1.5, False)
    """
    target = Path(target)
    materials = find_materials(target)
    if manifest is not None and len(materials) > 1:
        raise InputError("--manifest names one sample's manifest; give one MATERIAL.json with it", field="--manifest")
    thresholds = Thresholds.from_toml(Path(config)) if config is not None else Thresholds()
    thresholds = thresholds.updated(**(overrides or {}))
    illuminants = tuple(illuminants)
    if not illuminants:
        raise InputError("expected one or more illuminant names, e.g. D65,A", field="--illuminant")
    base = target if target.is_dir() else target.parent
    out_dir = files.output_folder(Path(output) if output is not None else base / "reports", create=False)
    single = len(materials) == 1
    entries, broken = [], []
    for path in materials:
        try:
            report = validate_material(path, manifest=manifest, illuminants=illuminants, observer=observer,
                                       thresholds=thresholds, contexts=_contexts(context), draws=draws)  # fmt: skip
        except InputError as err:
            if single:
                raise
            broken.append(BrokenMaterial(path, err))  # one unreadable material must not stop a product line's batch
            continue
        folder = out_dir / report.material.name if not single or output is None else out_dir
        entries.append(write_report(report, folder))
    index = None
    if not single and entries:
        index = index_reports([(entry.document, entry.page) for entry in entries], out_dir)
    return Validated(tuple(materials), tuple(entries), tuple(broken), index)
