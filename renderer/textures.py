"""GL textures from numpy arrays for the layer pass: float textures of 1 to 4 channels and RGBA 2-D arrays, map
texels, a sampler for a depth texture's raw values. A current context is needed (:mod:`renderer.context`). The float
textures belong to :data:`renderer.texture_cache.cache` (equal texels give the same texture again; never delete one);
the caller deletes the sampler."""

from __future__ import annotations

import numpy as np

from renderer.context import GL
from renderer.texture_cache import Remembered, cache

#: Internal and client formats of a float texture of 1 to 4 channels (a shader reads missing channels as 0, alpha 1).
_FORMATS = {
    1: (GL.GL_R32F, GL.GL_RED),
    2: (GL.GL_RG32F, GL.GL_RG),
    3: (GL.GL_RGB32F, GL.GL_RGB),
    4: (GL.GL_RGBA32F, GL.GL_RGBA),
}


def float_texture(data: np.ndarray, linear: bool, wrap_s: bool = False) -> int:
    """``data`` (rows, columns, C) float, C = 1 to 4 channels, as an R32F, RG32F, RGB32F or RGBA32F texture, row 0 at
    t = 0; clamped at the edges (but for s with ``wrap_s``: an equirectangular map's seam). Cached: see the module."""
    if data.ndim != 3 or data.shape[2] not in _FORMATS:
        raise ValueError(f"a float texture takes (rows, columns, 1 to 4 channels) texels, got shape {data.shape}")
    return cache.texture(data, ("2d", linear, wrap_s), lambda texels: _upload_2d(texels, linear, wrap_s))


def _upload_2d(data: np.ndarray, linear: bool, wrap_s: bool) -> int:
    rows, columns, channels = data.shape
    internal, client = _FORMATS[channels]
    texture = GL.glGenTextures(1)
    GL.glBindTexture(GL.GL_TEXTURE_2D, texture)
    GL.glPixelStorei(GL.GL_UNPACK_ALIGNMENT, 4)
    GL.glTexImage2D(GL.GL_TEXTURE_2D, 0, internal, columns, rows, 0, client, GL.GL_FLOAT, data)
    filtering = GL.GL_LINEAR if linear else GL.GL_NEAREST
    GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MIN_FILTER, filtering)
    GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MAG_FILTER, filtering)
    GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_WRAP_S, GL.GL_REPEAT if wrap_s else GL.GL_CLAMP_TO_EDGE)
    GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_WRAP_T, GL.GL_CLAMP_TO_EDGE)
    GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
    return texture


def array_texture(texels: np.ndarray, wrap_s: bool = False) -> int:
    """(layers, rows, columns, 4) float texels as a bilinear RGBA32F 2-D array texture, clamped at the edges (but for
    s with ``wrap_s``). Cached: see the module."""
    return cache.texture(texels, ("array", wrap_s), lambda data: _upload_array(data, wrap_s))


def _upload_array(texels: np.ndarray, wrap_s: bool) -> int:
    layers, rows, columns = texels.shape[:3]
    texture = GL.glGenTextures(1)
    GL.glBindTexture(GL.GL_TEXTURE_2D_ARRAY, texture)
    GL.glPixelStorei(GL.GL_UNPACK_ALIGNMENT, 4)
    GL.glTexImage3D(GL.GL_TEXTURE_2D_ARRAY, 0, GL.GL_RGBA32F, columns, rows, layers, 0, GL.GL_RGBA, GL.GL_FLOAT, texels)
    for parameter, value in (
        (GL.GL_TEXTURE_MIN_FILTER, GL.GL_LINEAR),
        (GL.GL_TEXTURE_MAG_FILTER, GL.GL_LINEAR),
        (GL.GL_TEXTURE_WRAP_S, GL.GL_REPEAT if wrap_s else GL.GL_CLAMP_TO_EDGE),
        (GL.GL_TEXTURE_WRAP_T, GL.GL_CLAMP_TO_EDGE),
    ):
        GL.glTexParameteri(GL.GL_TEXTURE_2D_ARRAY, parameter, value)
    GL.glBindTexture(GL.GL_TEXTURE_2D_ARRAY, 0)
    return texture


def map_texels(values: np.ndarray) -> np.ndarray:
    """float32 texels (rows, columns, C) of a (rows, columns) map (C = 1) or a (rows, columns, C <= 4) one, flipped so
    that row 0 (v = 1) is at t = 1: as many channels as the map has, so that a one-channel map is hashed, uploaded and
    sampled as a quarter of an RGBA one. Made once for a frozen map (:func:`renderer.texture_cache.frozen`), and then
    frozen too."""
    return _texels.get(values, _flipped)


def _flipped(values: np.ndarray) -> np.ndarray:
    values = np.asarray(values, dtype=np.float32)
    values = values[..., None] if values.ndim == 2 else values
    texels = np.ascontiguousarray(values[::-1])
    texels.setflags(write=False)
    return texels


_texels = Remembered()


def raw_depth_sampler() -> int:
    """A sampler object reading a depth texture's values (no comparison), nearest texel, clamped at the edges."""
    sampler = int(GL.glGenSamplers(1))
    for parameter, value in (
        (GL.GL_TEXTURE_COMPARE_MODE, GL.GL_NONE),
        (GL.GL_TEXTURE_MIN_FILTER, GL.GL_NEAREST),
        (GL.GL_TEXTURE_MAG_FILTER, GL.GL_NEAREST),
        (GL.GL_TEXTURE_WRAP_S, GL.GL_CLAMP_TO_EDGE),
        (GL.GL_TEXTURE_WRAP_T, GL.GL_CLAMP_TO_EDGE),
    ):
        GL.glSamplerParameteri(sampler, parameter, value)
    return sampler
