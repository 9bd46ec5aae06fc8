"""GL textures from numpy arrays for the layer pass: float RGBA textures and 2-D arrays, map texels, a sampler for a
depth texture's raw values. A current context is needed (:mod:`renderer.context`). The float textures belong to
:data:`renderer.texture_cache.cache` (equal texels give the same texture again; never delete one); the caller deletes
the sampler."""

from __future__ import annotations

import numpy as np

from renderer.context import GL
from renderer.texture_cache import cache


def float_texture(data: np.ndarray, linear: bool, wrap_s: bool = False) -> int:
    """``data`` (rows, columns, 4) float as an RGBA32F texture, row 0 at t = 0; clamped at the edges (but for s with
    ``wrap_s``: an equirectangular map's seam). Cached: see the module."""
    return cache.texture(data, ("2d", linear, wrap_s), lambda texels: _upload_2d(texels, linear, wrap_s))


def _upload_2d(data: np.ndarray, linear: bool, wrap_s: bool) -> int:
    rows, columns = data.shape[:2]
    texture = GL.glGenTextures(1)
    GL.glBindTexture(GL.GL_TEXTURE_2D, texture)
    GL.glPixelStorei(GL.GL_UNPACK_ALIGNMENT, 4)
    GL.glTexImage2D(GL.GL_TEXTURE_2D, 0, GL.GL_RGBA32F, columns, rows, 0, GL.GL_RGBA, GL.GL_FLOAT, data)
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
    """RGBA texels of a (rows, columns) or (rows, columns, <= 4) map, flipped so that row 0 (v = 1) is at t = 1."""
    values = np.asarray(values, dtype=float)
    values = values[..., None] if values.ndim == 2 else values
    texels = np.zeros((*values.shape[:2], 4), dtype=np.float32)
    texels[..., : values.shape[2]] = values[::-1]
    return texels


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
