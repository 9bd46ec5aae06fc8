"""GL textures kept from frame to frame, found again by their content.

The frames of a turntable (and the tiles of a supersampled frame) upload the same tables, cosmetic maps, skin maps and
environment maps again and again: on llvmpipe a 1024 x 1024 RGBA32F texture costs 20-60 ms to upload (most of it the
first touch of fresh memory), a face frame about 0.3 s in all. The cache hands back the texture it already holds for
texels of the same bytes, shape and sampling (a SHA-1 digest of them, about 0.7 ms per MB), so equal input always gives
an equal texture and changed input a new one.

An array the renderer cannot see change (:func:`frozen`: read-only, over read-only memory: kmpipe freezes the maps it
loads) is hashed once: its digest is remembered with the array (:class:`Remembered`) for as long as it lives, so that
the frames of a turntable and the tiles of a review that share a map do not hash its megabytes again.

Textures belong to the cache: callers never delete them. The cache keeps at most :data:`BUDGET_BYTES` of texels; past
that it deletes the least recently used textures, but none used since the last :func:`new_frame` (a pass calls it
before it asks for its textures, so that nothing it has bound disappears while it draws). The one GL context of the
process (:mod:`renderer.context`) owns them all and must be current when the cache is used.
"""

from __future__ import annotations

import hashlib
import weakref
from collections import OrderedDict
from collections.abc import Callable

import numpy as np

from renderer.context import GL

#: Most bytes of texels the cache keeps past the current frame's.
BUDGET_BYTES = 1 << 30


def frozen(values: object) -> bool:
    """Whether ``values`` is a numpy array that nothing can change without first making it writeable again: read-only,
    and so is every array it views, down to memory it owns or an immutable ``bytes``."""
    if not isinstance(values, np.ndarray):
        return False
    while isinstance(values, np.ndarray):
        if values.flags.writeable:
            return False
        values = values.base
    return values is None or isinstance(values, bytes)


class Remembered:
    """Values computed from :func:`frozen` arrays, kept with each array (by identity) while it lives."""

    def __init__(self) -> None:
        self._values: dict[int, tuple[weakref.ref, object]] = {}

    def get(self, source: np.ndarray, compute: Callable[[np.ndarray], object]) -> object:
        """``compute(source)``, remembered for a frozen ``source`` (else computed every time)."""
        if not frozen(source):
            return compute(source)
        key = id(source)
        found = self._values.get(key)
        if found is not None and found[0]() is source:
            return found[1]
        value = compute(source)
        self._values[key] = (weakref.ref(source, lambda _, key=key: self._values.pop(key, None)), value)
        return value


class TextureCache:
    """Textures by digest of their texels, least recently used first; see the module."""

    def __init__(self, budget_bytes: int = BUDGET_BYTES) -> None:
        self.budget_bytes = budget_bytes
        # (digest, sampling) -> (texture, bytes, frame)
        self._entries: OrderedDict[tuple, tuple[int, int, int]] = OrderedDict()
        self._frame = 0
        self._digests = Remembered()

    def new_frame(self) -> None:
        """Start a frame: the textures used from here on are not evicted until the next call."""
        self._frame += 1

    def texture(self, texels: np.ndarray, sampling: tuple, upload: Callable[[np.ndarray], int]) -> int:
        """The texture of float32 ``texels`` sampled as ``sampling`` says: the cached one, or ``upload(texels)``."""
        texels = np.ascontiguousarray(texels, dtype=np.float32)
        key = (self._digests.get(texels, _digest), sampling)
        if key in self._entries:
            texture, size, _ = self._entries.pop(key)
            self._entries[key] = (texture, size, self._frame)
            return texture
        texture = upload(texels)
        self._entries[key] = (texture, texels.nbytes, self._frame)
        self._evict()
        return texture

    def _evict(self) -> None:
        total = sum(size for _, size, _ in self._entries.values())
        for key in list(self._entries):
            if total <= self.budget_bytes:
                return
            texture, size, frame = self._entries[key]
            if frame == self._frame:
                continue  # bound, or about to be, by the frame being drawn
            del self._entries[key]
            GL.glDeleteTextures(1, [texture])
            total -= size

    def __len__(self) -> int:
        return len(self._entries)

    def clear(self) -> None:
        """Delete every texture the cache holds."""
        if self._entries:
            GL.glDeleteTextures(len(self._entries), [texture for texture, _, _ in self._entries.values()])
        self._entries.clear()


def _digest(texels: np.ndarray) -> bytes:
    """SHA-1 of the texels' shape and bytes."""
    digest = hashlib.sha1(repr(texels.shape).encode(), usedforsecurity=False)
    digest.update(memoryview(texels).cast("B"))
    return digest.digest()


#: The process's cache (its context's textures).
cache = TextureCache()
