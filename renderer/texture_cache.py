"""GL textures kept from frame to frame, found again by their content.

The frames of a turntable (and the tiles of a supersampled frame) upload the same tables, cosmetic maps, skin maps and
environment maps again and again: on llvmpipe a 1024 x 1024 RGBA32F texture costs 20-60 ms to upload (most of it the
first touch of fresh memory), a face frame about 0.3 s in all. The cache hands back the texture it already holds for
texels of the same bytes, shape and sampling (a SHA-1 digest of them, about 0.7 ms per MB), so equal input always gives
an equal texture and changed input a new one.

Textures belong to the cache: callers never delete them. The cache keeps at most :data:`BUDGET_BYTES` of texels; past
that it deletes the least recently used textures, but none used since the last :func:`new_frame` (a pass calls it
before it asks for its textures, so that nothing it has bound disappears while it draws). The one GL context of the
process (:mod:`renderer.context`) owns them all and must be current when the cache is used.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from collections.abc import Callable

import numpy as np

from renderer.context import GL

#: Most bytes of texels the cache keeps past the current frame's.
BUDGET_BYTES = 1 << 30


class TextureCache:
    """Textures by digest of their texels, least recently used first; see the module."""

    def __init__(self, budget_bytes: int = BUDGET_BYTES) -> None:
        self.budget_bytes = budget_bytes
        self._entries: OrderedDict[bytes, tuple[int, int, int]] = OrderedDict()  # digest -> (texture, bytes, frame)
        self._frame = 0

    def new_frame(self) -> None:
        """Start a frame: the textures used from here on are not evicted until the next call."""
        self._frame += 1

    def texture(self, texels: np.ndarray, sampling: tuple, upload: Callable[[np.ndarray], int]) -> int:
        """The texture of float32 ``texels`` sampled as ``sampling`` says: the cached one, or ``upload(texels)``."""
        texels = np.ascontiguousarray(texels, dtype=np.float32)
        digest = hashlib.sha1(repr((texels.shape, sampling)).encode(), usedforsecurity=False)
        digest.update(memoryview(texels).cast("B"))
        key = digest.digest()
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


#: The process's cache (its context's textures).
cache = TextureCache()
