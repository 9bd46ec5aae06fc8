"""The bundled head's uv texels and the 3-D points they cover, for scripts that paint maps over its uv.

A map of the head is an image over its uv square, ``size`` x ``size`` texels, row 0 at v = 1 (the image's top), texel
centres at ((column + 0.5) / size, 1 - (row + 0.5) / size). Each texel inside a uv triangle covers the point of the
head that the triangle's corners interpolate to there (barycentric weights in uv); painting a map as a function of
that 3-D point (mm, +y up, the face towards +z) keeps it continuous across the uv seams.

Import it from a script beside it or with ``recipes/head`` on ``sys.path``; it imports only numpy.
"""

from __future__ import annotations

import numpy as np


def smoothstep(lo: float, hi: float, x: np.ndarray) -> np.ndarray:
    """0 below lo, 1 above hi, 3 t^2 - 2 t^3 between (t = (x - lo) / (hi - lo)); lo > hi gives the falling step."""
    t = np.clip((np.asarray(x, dtype=float) - lo) / (hi - lo), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def hairline_mm(azimuth_deg: np.ndarray) -> np.ndarray:
    """The bundled head's hairline: its height y (mm) by azimuth about the head's vertical axis (degrees, 0 at the
    face, either side): the forehead, the temples, a sideburn before the ear, over the ear, the nape. The skin maps'
    paler scalp starts here, and the cosmetic map's foundation stops here."""
    knots = [0.0, 25.0, 38.0, 46.0, 50.0, 53.0, 56.0, 75.0, 90.0, 120.0, 150.0, 180.0]
    heights = [76.0, 72.0, 60.0, 35.0, 5.0, 5.0, 32.0, 30.0, 10.0, -30.0, -55.0, -60.0]
    return np.interp(np.abs(azimuth_deg), knots, heights)


def texel_points(mesh, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The head's point (mm) at each texel's centre (size, size, 3), where the uv islands cover (size, size) and the
    triangle covering each texel (size, size; -1 where none does).

    Texels up to 2 % of a triangle's barycentric range past its edges count as covered (no gaps along the seams);
    where triangles share a texel the last one drawn keeps it.
    """
    uv = mesh.visual.uv * size - 0.5  # texel centres at integers; row 0 is v = 1 (the image's top)
    uv[:, 1] = size - 1 - uv[:, 1]
    points, triangle = np.zeros((size, size, 3)), np.full((size, size), -1, np.int64)
    for index, tri in enumerate(mesh.faces):
        corners = uv[tri]
        lo, hi = np.floor(corners.min(axis=0)).astype(int), np.ceil(corners.max(axis=0)).astype(int) + 1
        xs, ys = np.meshgrid(np.arange(max(lo[0], 0), min(hi[0], size)), np.arange(max(lo[1], 0), min(hi[1], size)))
        (ax, ay), (bx, by), (cx, cy) = corners
        area = (bx - ax) * (cy - ay) - (cx - ax) * (by - ay)
        if area == 0:
            continue
        w1 = ((xs - ax) * (cy - ay) - (cx - ax) * (ys - ay)) / area
        w2 = ((bx - ax) * (ys - ay) - (xs - ax) * (by - ay)) / area
        w0 = 1.0 - w1 - w2
        inside = (w0 >= -0.02) & (w1 >= -0.02) & (w2 >= -0.02)
        p = mesh.vertices[tri]
        points[ys[inside], xs[inside]] = w0[inside, None] * p[0] + w1[inside, None] * p[1] + w2[inside, None] * p[2]
        triangle[ys[inside], xs[inside]] = index
    return points, triangle >= 0, triangle


def texel_frames(mesh, size: int, triangle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per texel, the head's step (mm, a 3-vector) for one texel along +u and along +v; each (size, size, 3), zero
    where ``triangle`` is -1.

    Within a triangle the point is linear in uv, P = P0 + (u - u0) T + (v - v0) B, so the steps are its exact
    derivatives T / size and B / size (the finite differences of :func:`texel_points` inside the triangle), solved
    from the corners: [P1 - P0; P2 - P0] = [u1 - u0, v1 - v0; u2 - u0, v2 - v0] [T; B]. Their lengths are the mm
    per texel along u and v; +v is up the image (towards row 0).
    """
    p, uv = mesh.vertices[mesh.faces], mesh.visual.uv[mesh.faces]
    edges = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]], axis=1)  # (n, 2, 3)
    duv = np.stack([uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]], axis=1)  # (n, 2, 2)
    det = duv[:, 0, 0] * duv[:, 1, 1] - duv[:, 0, 1] * duv[:, 1, 0]
    det = np.where(np.abs(det) > 1e-15, det, 1e-15)
    tangent = (duv[:, 1, 1, None] * edges[:, 0] - duv[:, 0, 1, None] * edges[:, 1]) / det[:, None]
    bitangent = (duv[:, 0, 0, None] * edges[:, 1] - duv[:, 1, 0, None] * edges[:, 0]) / det[:, None]
    inside = triangle >= 0
    steps = []
    for per_face in (tangent / size, bitangent / size):
        texels = np.zeros((*triangle.shape, 3))
        texels[inside] = per_face[triangle[inside]]
        steps.append(texels)
    return steps[0], steps[1]


def mouth(mesh) -> tuple[float, float, float]:
    """The mouth line's height and the upper and lower lips' forward peaks (y, mm) from the face's midline profile.

    The profile: the vertices on the midline (|x| < 0.5 mm) below the nose's tip (the most forward one), less than
    25 mm behind it and facing forward (normal z > 0: the outer skin, not the inside of the mouth), from the tip
    down. Going down it, the first low point is under the nose, the next high point the upper lip's peak, the next
    low point where the lips meet and the next high point the lower lip's peak; the mouth line lies halfway between
    the two peaks. (The most forward point below the nose alone would be the nose's own underside.)
    """
    on_midline = np.abs(mesh.vertices[:, 0]) < 0.5
    tip = mesh.vertices[on_midline][np.argmax(mesh.vertices[on_midline, 2])]
    front = (mesh.vertex_normals[:, 2] > 0.0) & (mesh.vertices[:, 2] > tip[2] - 25.0)
    outer = on_midline & front & (mesh.vertices[:, 1] <= tip[1])
    profile = mesh.vertices[outer][np.argsort(-mesh.vertices[outer, 1], kind="stable")]
    z, i = profile[:, 2], 0
    turns = []
    for rising in (False, True, False, True):  # down to under the nose, up the upper lip, down, up the lower lip
        while i + 1 < len(z) and (z[i + 1] >= z[i] if rising else z[i + 1] <= z[i]):
            i += 1
        turns.append(i)
    upper, lower = profile[turns[1], 1], profile[turns[3], 1]
    return (upper + lower) / 2.0, upper, lower


LIP_HALF_WIDTH_MM = 25.0
"""Half the mouth's width (mm): the lip outline closes at |x| = this."""


def lip_outline(points: np.ndarray, mesh) -> np.ndarray:
    """How far (mm) each point lies outside the lips' outline, negative inside (points (..., 3), mm).

    The outline runs between the mouth line and an upper and a lower lip contour, each a half-ellipse-like arc
    height (peak - line + margin) (1 - (x / half width)^2)^p (p 0.7 upper, 0.6 lower) over |x| < 25 mm, the upper one
    dipped 1.5 exp(-(x / 5 mm)^2) at the middle (the Cupid's bow); margins 4 mm (upper) and 5 mm (lower) past the
    lips' forward peaks (:func:`mouth`). Points at |x| >= 25 mm or behind z = 75 mm lie 1000 mm outside. The distance
    is measured vertically, |y - line| - arc height.
    """
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    line, upper, lower = mouth(mesh)
    across = np.clip(np.abs(x) / LIP_HALF_WIDTH_MM, 0.0, 1.0)
    bow = 1.5 * np.exp(-((x / 5.0) ** 2))
    top = (upper - line + 4.0) * np.sqrt(1.0 - across**2) ** 0.7 - bow
    bottom = (line - lower + 5.0) * np.sqrt(1.0 - across**2) ** 0.6
    edge = np.abs(y - line) - np.where(y > line, top, bottom)
    return np.where((np.abs(x) < LIP_HALF_WIDTH_MM) & (z > 75.0), edge, 1000.0)
