"""What to measure next, as a plan: a measurement plan with the best addition a validation found appended
(``kmpipe measure PLAN --add-suggested VALIDATION.json``).

The addition is validation.json's ``uncertainty.next_measurement[0]`` (:mod:`kmpipe.validation.uncertainty`): a film
of a thickness over a backing (with the thickness uncertainty the suggestion assumed), a masstone, or a repeat of a
reading (a ``[[film]]`` of the same thickness and backing under a reading name of its own). The new plan,
``PLAN.next.toml`` beside the plan, is the plan's text with that table appended, so a whole session is measured with
it: radiance readings need the white standard and the backings read in the same session.
"""

from __future__ import annotations

from pathlib import Path

from kmpipe.errors import InputError
from kmpipe.formats import files
from kmpipe.formats.atomic_write import write_text_atomically
from kmpipe.formats.measurement_plan import load_plan, positions


def _suggestion(validation: Path) -> dict:
    document = files.read_json(validation, "JSON", "validation report")
    found = (document.get("uncertainty") or {}).get("next_measurement") if isinstance(document, dict) else None
    if not found:
        raise InputError("holds no suggested measurement (uncertainty.next_measurement is empty or missing; validate "
                         "a spectral material with kmpipe validate first)", path=validation,
                         field="uncertainty.next_measurement")  # fmt: skip
    best = found[0]
    if not isinstance(best, dict) or best.get("role") not in ("film", "masstone", "repeat"):
        raise InputError("expected a role of film, masstone or repeat", path=validation,
                         field="uncertainty.next_measurement[1].role")  # fmt: skip
    return best


def _table(best: dict, taken: set[str]) -> str:
    """The TOML table of the addition; a repeat gets a reading name not yet ``taken``."""
    if best["role"] == "masstone" or (best["role"] == "repeat" and best.get("over") is None):
        return "[[masstone]]\n"
    thickness = best["thickness"]
    if best.get("thickness_u"):
        thickness += f" +- {best['thickness_u']}"
    text = f'[[film]]\nover = "{best["over"]}"\nthickness = "{thickness}"\n'
    if best["role"] == "repeat" or f"film_{best['thickness'].replace(' ', '')}_over_{best['over']}" in taken:
        stem = f"film_{best['thickness'].replace(' ', '')}_over_{best['over']}_added"
        name = next(f"{stem}{i or ''}" for i in range(100) if f"{stem}{i or ''}" not in taken)
        text += f'name = "{name}"\n'
    return text


def add_suggestion(plan_path: Path, validation: Path) -> tuple[Path, str]:
    """Write ``PLAN.next.toml``: the plan with the validation's best addition; returns its path and the suggestion's
    line. InputError (exit 2) for a validation without a suggestion, or a ``.next.toml`` already there with another
    addition (a session may be measuring it: remove it first)."""
    plan_path, validation = Path(plan_path), Path(validation)
    plan = load_plan(plan_path)
    best = _suggestion(validation)
    taken = {p.column for p in positions(plan, lambda i, film: "1 um")}
    text = files.read_text(plan_path, "TOML", field="plan").rstrip("\n") + "\n"
    text += f"\n# added by kmpipe measure --add-suggested {validation.name}: {best.get('line', '')}\n"
    text += _table(best, taken)
    target = plan_path.with_name(plan_path.stem + ".next.toml")
    if files.is_regular(target) and target.read_text(encoding="utf-8") != text:
        raise InputError("already holds another addition to the plan; remove it (or measure it) first",
                         path=target, field="--add-suggested")  # fmt: skip
    write_text_atomically(target, text)
    load_plan(target)  # the addition names a backing of the plan and a free reading name
    return target, str(best.get("line", ""))
