"""The light of a scene file (:mod:`kmpipe.formats.scene`): its ``[[light]]`` lights, ``[environment]`` and what
stands around the product, ``[ground]`` or ``[backdrop]``.

* ``[[light]]``: directional (``direction`` towards the light) or point (``position``, mm) lights with a
  ``radiance`` (linear RGB; 1 makes a white Lambert surface facing the light render as 1); an area light's size
  softens its shadows: ``angle_deg`` (a directional light's angular diameter, e.g. a softbox 1 m away and 0.5 m wide
  is about 28 degrees) or ``size_mm`` (a point light's diameter).
* ``[environment]``: image-based light from an equirectangular HDR (``file``: Radiance ``.hdr`` or OpenEXR, linear
  RGB, twice as wide as tall; without ``file``, the built-in studio, :func:`renderer.environment.studio_environment`),
  turned by ``rotation_deg`` about the vertical and scaled by ``intensity``; ``visible = true`` shows it behind the
  product.
* ``[ground]``: a square floor of ``reflectance`` under the product; ``[backdrop]``: a seamless paper sweep
  (``kind = "sweep"``, a floor curving up into a wall behind the product, of ``reflectance``) or a vertical gradient
  behind it (``kind = "gradient"``, ``top`` and ``bottom`` linear RGB).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, model_validator

from kmpipe.errors import InputError
from kmpipe.formats.surface_maps import image_file
from kmpipe.formats.toml_input import StrictModel

#: Largest light radiance (linear RGB per channel, 1 = a white Lambert surface renders as white): far above any
#: exposure the output's +-20 EV can bring back, far below float32's range after the inverse-square falloff.
MAX_RADIANCE = 1e6
#: Largest distance or coordinate (mm) of a light or the camera: 100 m.
MAX_DISTANCE_MM = 1e5
#: Shortest direction vector of a directional light (its length is otherwise free).
MIN_DIRECTION = 1e-6
#: Largest angular diameter (degrees) of a directional area light.
MAX_LIGHT_ANGLE_DEG = 90.0

_Coordinate = Annotated[float, Field(ge=-MAX_DISTANCE_MM, le=MAX_DISTANCE_MM)]
_Vector = tuple[_Coordinate, _Coordinate, _Coordinate]
_Radiance = Annotated[float, Field(ge=0.0, le=MAX_RADIANCE)]


class LightInfo(StrictModel):
    kind: Literal["directional", "point"] = "directional"
    direction: _Vector | None = None
    position: _Vector | None = None
    radiance: tuple[_Radiance, _Radiance, _Radiance] = (1.0, 1.0, 1.0)
    reference_distance_mm: float | None = Field(default=None, gt=0.0, le=MAX_DISTANCE_MM)
    shadows: bool = True
    size_mm: float = Field(default=0.0, ge=0.0, le=MAX_DISTANCE_MM)  # a point light's diameter: soft shadows
    angle_deg: float = Field(default=0.0, ge=0.0, le=MAX_LIGHT_ANGLE_DEG)  # a directional light's angular diameter

    @model_validator(mode="after")
    def _geometry(self) -> LightInfo:
        if self.kind == "directional":
            if self.position is not None or self.reference_distance_mm is not None or self.size_mm:
                raise ValueError(
                    "a directional light has a direction (and an angle_deg), not a position, reference_distance_mm "
                    "or size_mm"
                )
            vector = self.direction if self.direction is not None else (0.0, 0.0, 1.0)
            if not max(abs(v) for v in vector) >= MIN_DIRECTION:
                raise ValueError(
                    f"the direction towards the light must be a non-zero vector (a component of at least "
                    f"{MIN_DIRECTION:g} in size), got {vector}"
                )
        elif self.position is None or self.direction is not None or self.angle_deg:
            raise ValueError("a point light has a position (mm) (and a size_mm), no direction or angle_deg")
        return self


class GroundInfo(StrictModel):
    reflectance: float = Field(ge=0.0, le=1.0)


class EnvironmentInfo(StrictModel):
    file: str | None = Field(default=None, min_length=1)
    rotation_deg: float = Field(default=0.0, ge=-360.0, le=360.0)
    intensity: float = Field(default=1.0, ge=0.0, le=MAX_RADIANCE)
    visible: bool = False


_Colour = tuple[_Radiance, _Radiance, _Radiance]


class BackdropInfo(StrictModel):
    kind: Literal["sweep", "gradient"] = "sweep"
    reflectance: float | None = Field(default=None, ge=0.0, le=1.0)
    top: _Colour | None = None
    bottom: _Colour | None = None

    @model_validator(mode="after")
    def _fields_of_kind(self) -> BackdropInfo:
        if self.kind == "sweep" and (self.top is not None or self.bottom is not None):
            raise ValueError("a sweep has a reflectance (default 0.6), not top and bottom colours")
        if self.kind == "gradient" and self.reflectance is not None:
            raise ValueError("a gradient has top and bottom colours (linear RGB), not a reflectance")
        return self


#: Reflectance of a sweep when the scene gives none, and a gradient's default colours (linear RGB).
SWEEP_REFLECTANCE = 0.6
GRADIENT = ((0.30, 0.30, 0.31), (0.05, 0.05, 0.055))
#: Half width, in radii of the product's bounding sphere, of the floor (ground or sweep) around the product whose
#: ambient occlusion is baked (kmpipe.stages.staging.floor_occlusion); beyond it the floor sees the whole sky.
FLOOR_EXTENT = 3.0
#: Largest side (pixels) an environment image is kept at: larger ones are area-averaged down (the light needs
#: 128 x 64; the visible background a little more).
ENVIRONMENT_SIDE = 2048


def environment_radiance(info: EnvironmentInfo, base: Path, where: dict) -> np.ndarray:
    """The environment's equirectangular radiance, linear RGB float32 (rows, 2 rows, 3): the file's, or the built-in
    studio's; InputError at ``where`` for a file that is missing, not an image, not 2:1, negative or not finite."""
    import cv2

    from renderer.environment import studio_environment

    if info.file is None:
        return studio_environment()
    path, image, _ = image_file(base, info.file, "environment image (an HDR or EXR)", where)
    rows, cols, channels = image.shape
    if channels < 3 or cols != 2 * rows or rows < 4:
        raise InputError(
            f"{path} is {cols} x {rows} with {channels} channels: an equirectangular environment is RGB, twice as "
            "wide as it is tall (at least 8 x 4)",
            **where,
        )
    rgb = image[..., :3]
    if not (np.all(np.isfinite(rgb)) and rgb.min() >= 0.0 and rgb.max() <= MAX_RADIANCE):
        raise InputError(f"{path}: environment radiance must be finite and in [0, {MAX_RADIANCE:g}]", **where)
    if cols > ENVIRONMENT_SIDE:
        rgb = cv2.resize(rgb, (ENVIRONMENT_SIDE, ENVIRONMENT_SIDE // 2), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(rgb, dtype=np.float32)
