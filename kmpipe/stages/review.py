"""The shade review's rows: one skin tone against every foundation of a line, under every illuminant of the review.

A row is the numbers (:mod:`kmpipe.physics.shade_match`: coverage, match, best shade, metamerism of each worn
pair) and, per foundation and illuminant, a render tile of the product worn at its usual thickness on the bundled
head's cheek (the skin a uniform film of the tone's own spectrum, with the head's normal and roughness maps, its
subsurface scattering, a soft key, the studio environment and a grey gradient behind, one sample a pixel), with a
swatch of the exact made-up colour in its corner; and the bare skin's tile per illuminant. Tiles are rendered under
the illuminant and adapted to D65 (CAT02) as a viewer adapted to that light sees them
(:mod:`kmpipe.physics.optical_tables`), swatches the same way (:func:`kmpipe.physics.colorimetry.reflectance_to_sRGB`);
every tile is tone mapped by one curve, whose white is the white card of the tiles' common light
(:mod:`renderer.scene_white`), so a white card would be display white in a tile as in a swatch.

The row is written into its own folder: ``row.json`` (docs/formats.md, "Shade reviews") and the tiles
``bare_ILLUMINANT.png`` and ``SHADE_ILLUMINANT.png``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import colour
import numpy as np

from kmpipe.formats.atomic_write import write_text_atomically
from kmpipe.formats.files import sha256
from kmpipe.formats.material import read_material
from kmpipe.formats.recipe import slug
from kmpipe.formats.scene import HEAD_DIR
from kmpipe.formats.skin_tones import SkinTone, read_tones
from kmpipe.physics.colorimetry import reflectance_to_Lab, reflectance_to_sRGB, register_illuminant
from kmpipe.physics.colour_uncertainty import colour_radius
from kmpipe.physics.shade_match import broken_matches, made_up, masstone, pair_delta_e, rank_shades, shift_words

#: Where the tiles look: the left cheek of the bundled head, from the camera's side (mm, from the head's centre).
CHEEK_AIM_MM = (35.0, -20.0, 40.0)
#: Side of a swatch in a tile, as a fraction of the tile.
SWATCH = 0.22


def _tile_data(tone_csv: Path, tone: str, material: Path, illuminant: str, size: int) -> dict:
    """Scene data of a tile: the head, its skin the tone, one film (thickness set per tile), framed on the cheek."""
    return {
        "scene": {"name": "Shade review", "illuminant": illuminant, "mesh": "head", "resolution": [size, size]},
        "skin": {
            "reflectance": f"{tone_csv}:{tone}",
            "normal_map": str(HEAD_DIR / "head_normal.png"),
            "roughness_map": str(HEAD_DIR / "head_roughness.png"),
        },
        "layer": [{"material": str(material), "thickness": "10 um", "specular": {"roughness": 0.45, "ior": 1.5}}],
        "light": [{"direction": [0.6, 0.5, 0.8], "radiance": [0.8, 0.8, 0.8], "angle_deg": 20.0}],
        "environment": {"intensity": 0.8},
        "backdrop": {"kind": "gradient", "top": [0.3, 0.3, 0.3], "bottom": [0.12, 0.12, 0.12]},
        "camera": {
            "azimuth_deg": 35.0,
            "elevation_deg": 0.0,
            "distance_mm": 420.0,
            "fov_deg": 16.0,
            "aim_mm": list(CHEEK_AIM_MM),
        },
        "output": {"tone_map": "reinhard", "antialias": 1},  # shown at half size: no silhouette to smooth
    }


class _Tiles:
    """Renders a row's tiles: the head, its maps and its ambient occlusion loaded and baked once for the row, each
    tile then only its film, thickness and illuminant."""

    def __init__(self, tone: SkinTone, material: Path, folder: Path, size: int) -> None:
        from kmpipe.formats.scene import build_scene
        from kmpipe.formats.spectra import SpectralTable, write_spectra_csv

        csv = folder / "tone.csv"
        write_spectra_csv(SpectralTable(tone.wavelengths, None, (tone.id,), tone.reflectance[None, :],
                                        {"quantity": "reflectance", "units": "1"}), csv)  # fmt: skip
        data = _tile_data(csv, tone.id, material, "D65", size)
        self.scene = build_scene(data, folder / "tile.toml", folder, lambda loc: {"field": ".".join(map(str, loc))})
        self.occlusion = None

    def render(self, material, material_hash: str, thickness_mm: float, illuminant: str) -> np.ndarray:
        from kmpipe.stages import staging
        from kmpipe.stages.render import renderer_scenes
        from kmpipe.stages.render_plan import plan_scene
        from renderer.scene_white import scene_white
        from renderer.skin import render_skin
        from renderer.tone_map import tone_map

        info = self.scene.info
        info = info.model_copy(update={"scene": info.scene.model_copy(update={"illuminant": illuminant})})
        scene = dataclasses.replace(self.scene, info=info, materials=(material,), material_hashes=(material_hash,),
                                    thicknesses_mm=(thickness_mm,))  # fmt: skip
        plan = plan_scene(scene)
        if self.occlusion is None and plan.ambient_occlusion:
            self.occlusion = staging.occlusion(scene)
        [frame] = renderer_scenes(scene, plan, [0.0], occlusion=self.occlusion)  # the row's head: baked once
        # One tone curve for every tile (the white card of their common light), so tiles compare as they are lit.
        return tone_map(render_skin(frame), "reinhard", white=scene_white(frame))


def _radius(material, thickness_mm: float, skin: np.ndarray, illuminant: str) -> float | None:
    """The 95 % Delta E 2000 radius of the colour of ``material`` at ``thickness_mm`` over ``skin``
    (:func:`kmpipe.physics.colour_uncertainty.colour_radius`, from the material's budget), or None without one."""
    if material.budget is None:
        return None
    return round(colour_radius(material.budget, thickness_mm, skin, material.wavelengths, illuminant), 3)


def _within(ranking, masstone_doubt: list[float | None]) -> bool | None:
    """Whether the best shade's margin over the second lies within either masstone's radius (the two cannot be
    told apart on the readings' evidence); None where that cannot be said."""
    if ranking.second is None or ranking.margin is None:
        return None
    radii = [masstone_doubt[ranking.best], masstone_doubt[ranking.second]]
    if any(r is None for r in radii):
        return None
    return bool(ranking.margin <= max(radii))


def _with_swatch(tile: np.ndarray, srgb: np.ndarray) -> np.ndarray:
    """The tile (linear RGB) with a swatch of display colour ``srgb`` (encoded) in its lower right corner, framed."""
    out = np.array(tile, dtype=float)
    side = max(4, round(SWATCH * min(out.shape[:2])))
    out[-side - 2 :, -side - 2 :] = 1.0
    out[-side:, -side:] = colour.cctf_decoding(srgb, function="sRGB")
    return out


def _hex(srgb: np.ndarray) -> str:
    """``#rrggbb`` of display sRGB in [0, 1]."""
    return "#" + "".join(f"{round(float(c) * 255):02x}" for c in srgb)


def review_row(
    tone_source: str,
    tone_id: str,
    base: str,
    foundations: list[dict],
    illuminants: list[str],
    reference: str,
    threshold: float,
    out: str,
    tile: int,
    illuminant_files: dict[str, tuple[str, str | None]] | None = None,
) -> dict:
    """One tone's row of the review into folder ``out``: ``row.json`` and the tiles; returns the row.

    ``foundations``: dicts of ``name``, ``shade``, ``material`` (a MATERIAL.json path) and ``thickness_mm``, all on
    one wavelength grid; the tone is ``tone_id`` of the source ``tone_source`` (paths relative to ``base``);
    ``illuminant_files``: the illuminants read from SPD files, name -> (path, column).
    """
    from renderer.image_io import write_png

    for name, (path, column) in (illuminant_files or {}).items():
        register_illuminant(name, path, column)  # in this (worker) process
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    materials = [read_material(f["material"]) for f in foundations]
    wavelengths = materials[0].wavelengths
    [tone] = [t for t in read_tones([tone_source], wavelengths, Path(base), {"field": "review.tones"})
              if t.id == tone_id]  # fmt: skip
    skin = tone.reflectance
    worn = np.stack([made_up(m.K, m.S, f["thickness_mm"], skin) for m, f in zip(materials, foundations, strict=True)])
    full = np.stack([masstone(m.K, m.S) for m in materials])
    coverage = pair_delta_e(worn, skin, wavelengths, illuminants)  # (illuminants, shades)
    match = pair_delta_e(full, skin, wavelengths, illuminants)
    ref = illuminants.index(reference)
    ranking = rank_shades(match[ref])
    worn_breaks = broken_matches(coverage, ref, threshold)
    shade_breaks = broken_matches(match, ref, threshold)
    doubt = {(i, ill): _radius(m, f["thickness_mm"], skin, ill) for i, (m, f) in enumerate(zip(materials, foundations,
             strict=True)) for ill in illuminants}  # fmt: skip
    masstone_doubt = [_radius(m, math.inf, skin, reference) for m in materials]
    tiles = _Tiles(tone, Path(foundations[0]["material"]), folder, tile)
    bare = {}
    for ill in illuminants:
        name, srgb = f"bare_{slug(ill)}.png", reflectance_to_sRGB(skin, wavelengths, ill)
        write_png(folder / name, _with_swatch(tiles.render(materials[0], "bare", 0.0, ill), srgb))
        bare[ill] = {"srgb": _hex(srgb), "tile": name, "lab": reflectance_to_Lab(skin, wavelengths, ill)}
    cells = []
    for i, (material, f) in enumerate(zip(materials, foundations, strict=True)):
        per_illuminant = {}
        digest = sha256(f["material"])
        for j, ill in enumerate(illuminants):
            lab_worn = reflectance_to_Lab(worn[i], wavelengths, ill)
            name = f"{slug(f['shade'])}_{slug(ill)}.png"
            swatch = reflectance_to_sRGB(worn[i], wavelengths, ill)
            write_png(folder / name, _with_swatch(tiles.render(material, digest, f["thickness_mm"], ill), swatch))
            per_illuminant[ill] = {
                "coverage_delta_e": round(float(coverage[j, i]), 3),
                "match_delta_e": round(float(match[j, i]), 3),
                "made_up_lab": [round(float(v), 3) for v in lab_worn],
                "masstone_lab": [round(float(v), 4) for v in reflectance_to_Lab(full[i], wavelengths, ill)],
                "made_up_srgb": _hex(swatch),
                "uncertainty_delta_e": doubt[i, ill],
                "worn_match_breaks": bool(worn_breaks[j, i]),
                "shade_match_breaks": bool(shade_breaks[j, i]),
                "shift": shift_words(lab_worn, bare[ill]["lab"]),
                "tile": name,
            }
        cells.append({"product": f["name"], "shade": f["shade"], "thickness_mm": f["thickness_mm"],
                      "illuminants": per_illuminant})  # fmt: skip
    shades = [f["shade"] for f in foundations]
    row = {
        "tone": {
            "id": tone.id,
            "name": tone.name,
            "kind": tone.kind,
            "source": tone.source,
            "site": tone.site,
            "lab_d65_10": [round(float(v), 3) for v in tone.lab],
            "ita_deg": round(tone.ita_deg, 2),
            "ita_class": tone.ita_class,
        },
        "bare": {ill: {"srgb": values["srgb"], "tile": values["tile"]} for ill, values in bare.items()},
        "best": shades[ranking.best],
        "second": None if ranking.second is None else shades[ranking.second],
        "margin_delta_e": None if ranking.margin is None else round(ranking.margin, 3),
        "margin_within_uncertainty": _within(ranking, masstone_doubt),
        "cells": cells,
    }
    write_text_atomically(folder / "row.json", json.dumps(row, indent=1) + "\n")
    return {"row": str(folder / "row.json")}
