"""Check that two demo output folders hold the same results: materials, validation verdicts and every image.

Used to show that a restructuring changed no result: run ``./scripts/demo``, copy ``out/demo`` aside, change the
code, run the demo again, then::

    .venv/bin/python scripts/same_results.py BEFORE_DIR out/demo [--new plan.json]

Materials (``*.json`` with K and S) are compared on every field but their provenance (dates, versions, paths);
validation files (``validation.json``, ``summary.json``) on every field; images (``*.exr``, ``*.png``) pixel for
pixel through OpenImageIO, never by checksum (metadata such as a date may differ, the pixels may not). ``--new NAME``
names an output that the change adds (files of that name may exist only after; they are listed, not compared). Exit
status 0 when everything is equal, 1 when anything differs or is missing on one side (each difference is listed).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

#: Material fields that record when and where a material was made, not what it is.
PROVENANCE = {"provenance"}


def _pixels(path: Path) -> np.ndarray:
    image = oiio.ImageBuf(str(path))
    if image.has_error:
        raise OSError(f"{path}: {image.geterror()}")
    return image.get_pixels(oiio.FLOAT)


def _json_difference(before: object, after: object, where: str) -> str | None:
    """The first place two JSON values differ (exact: a restructuring must not move a single bit), or None."""
    if isinstance(before, dict) and isinstance(after, dict):
        if before.keys() != after.keys():
            return f"{where}: keys {sorted(before.keys() ^ after.keys())} on one side only"
        for key in before:
            found = _json_difference(before[key], after[key], f"{where}.{key}")
            if found:
                return found
        return None
    if isinstance(before, list) and isinstance(after, list):
        if len(before) != len(after):
            return f"{where}: {len(before)} vs {len(after)} items"
        for i, (b, a) in enumerate(zip(before, after, strict=True)):
            found = _json_difference(b, a, f"{where}[{i}]")
            if found:
                return found
        return None
    return None if before == after else f"{where}: {before!r} vs {after!r}"


def compare(before_dir: Path, after_dir: Path, new: frozenset[str] = frozenset()) -> tuple[dict[str, int], list[str]]:
    """Compare every result file of two output folders: (files compared per kind, differences found); files named
    in ``new`` may exist only after."""
    counts = {"materials": 0, "validation files": 0, "images": 0}
    problems: list[str] = []

    def results(root: Path) -> set[Path]:
        return {
            p.relative_to(root)
            for p in root.rglob("*")
            if p.is_file() and ".kmpipe" not in p.parts and p.suffix in (".json", ".exr", ".png")
        }

    before, after = results(before_dir), results(after_dir)
    problems += [f"{p}: only in {before_dir}" for p in sorted(before - after)]
    problems += [f"{p}: only in {after_dir}" for p in sorted(after - before) if p.name not in new]
    for relative in sorted(before & after):
        b, a = before_dir / relative, after_dir / relative
        if relative.suffix == ".json":
            old, new = json.loads(b.read_text()), json.loads(a.read_text())
            if isinstance(old, dict) and "K" in old and "S" in old:
                counts["materials"] += 1
                old = {k: v for k, v in old.items() if k not in PROVENANCE}
                new = {k: v for k, v in new.items() if k not in PROVENANCE}
            elif relative.name in ("validation.json", "summary.json"):
                counts["validation files"] += 1
            else:
                continue  # sessions and other records carry dates
            found = _json_difference(old, new, str(relative))
            if found:
                problems.append(found)
        else:
            counts["images"] += 1
            old_pixels, new_pixels = _pixels(b), _pixels(a)
            if old_pixels.shape != new_pixels.shape:
                problems.append(f"{relative}: {old_pixels.shape} vs {new_pixels.shape} pixels")
            elif not np.array_equal(old_pixels, new_pixels):
                changed = int(np.count_nonzero(np.any(old_pixels != new_pixels, axis=-1)))
                worst = float(np.max(np.abs(old_pixels - new_pixels)))
                problems.append(f"{relative}: {changed} pixels differ (largest difference {worst:.3g})")
    return counts, problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("before", type=Path)
    parser.add_argument("after", type=Path)
    parser.add_argument("--new", action="append", default=[], metavar="NAME", help="an output the change adds")
    args = parser.parse_args(argv)
    counts, problems = compare(args.before, args.after, frozenset(args.new))
    print(", ".join(f"{n} {kind}" for kind, n in counts.items()) + " compared")
    for problem in problems:
        print("DIFFERENT", problem)
    print("same results" if not problems else f"{len(problems)} differences")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
