"""The arm's meshes in MuJoCo's binary mesh format, written once when the model is fetched.

robosuite's Sawyer ships ~55 MB of Wavefront OBJ text (233k vertices). MuJoCo parses it on
every compile: ~0.3 s of each daemon start, calibration, render and test process. The same
vertices, normals, texture coordinates and triangles in MuJoCo's binary ``.msh`` layout load
in a few milliseconds and compile to the same model, array for array (the test compares
them). The fetch writes one ``.msh`` per OBJ that ``robot.xml`` loads, named after the OBJ's
sha256 (:func:`fast_mesh_path`), and lists them in the manifest like every other file; a
model then loads the binary file only when the manifest lists it for the OBJ's current
content, so an OBJ changed and re-certified is read as it is.

Only OBJ files of the simple form are converted: ``v``, ``vn``, ``vt`` and triangular ``f``
records whose corners name the same index for position, texture coordinate and normal (the
form robosuite's exporter writes), normals and texture coordinates either absent or one per
vertex. Anything else stays an OBJ, which MuJoCo reads as before.
"""

from __future__ import annotations

import numpy as np

#: Where the fetch puts the binary meshes, relative to the model folder.
FAST_MESH_DIR = "fast_meshes"

#: OBJ records that carry nothing MuJoCo's loader uses (materials, groups, smoothing).
_IGNORED = {"#", "mtllib", "usemtl", "o", "g", "s"}


def fast_mesh_path(obj_sha256: str) -> str:
    """The relative path of the binary mesh converted from the OBJ with this sha256."""
    return f"{FAST_MESH_DIR}/{obj_sha256}.msh"


def _corner(text: str) -> int | None:
    """The one 1-based index of an ``f`` corner (``i``, ``i/i``, ``i//i``, ``i/i/i``), 0-based;
    None when the parts differ or are not positive integers."""
    raw = text.split("/")
    parts = [p for p in raw if p]
    if not parts or len(raw) > 3 or any(p != parts[0] for p in parts):
        return None
    if not parts[0].isdigit() or int(parts[0]) < 1:
        return None
    return int(parts[0]) - 1


def obj_to_msh(data: bytes) -> bytes | None:
    """MuJoCo ``.msh`` bytes holding what MuJoCo reads from this OBJ, or None when the OBJ
    is not of the simple form (see the module's docstring) and must stay as it is.

    The layout: four int32 counts (vertices, normals, texture coordinates, faces), then
    float32 positions, normals and texture coordinates and int32 triangles. Texture
    coordinates are flipped to MuJoCo's convention (``v -> 1 - v``), as its OBJ loader does.
    """
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError:
        return None
    # the coordinates as flat lists of their text, the corners as theirs: numpy converts
    # them at once, each distinct corner is read once (a vertex is the corner of ~6 faces)
    coords: dict[str, list[str]] = {"v": [], "vn": [], "vt": []}
    corners: list[str] = []
    for line in text.splitlines():
        fields = line.split()
        if not fields:
            continue
        key = fields[0]
        if key in coords:
            width = 2 if key == "vt" else 3
            if len(fields) - 1 not in (width, width + 1):  # a w or a third vt coordinate
                return None
            coords[key].extend(fields[1 : width + 1])
        elif key == "f":
            if len(fields) != 4:
                return None
            corners.extend(fields[1:])
        elif key not in _IGNORED and not key.startswith("#"):
            return None
    index: dict[str, int] = {}
    for corner in set(corners):
        i = _corner(corner)
        if i is None:
            return None
        index[corner] = i
    try:
        vert = np.array(coords["v"], dtype=np.float32).reshape(-1, 3)
        normal = np.array(coords["vn"], dtype=np.float32).reshape(-1, 3)
        tex = np.array(coords["vt"], dtype=np.float32).reshape(-1, 2)
    except ValueError:  # a coordinate that is not a number
        return None
    corner_index = np.fromiter(map(index.__getitem__, corners), np.int64, count=len(corners))
    n = len(vert)
    if n < 4 or len(corners) == 0 or len(normal) not in (0, n) or len(tex) not in (0, n):
        return None
    if not (np.isfinite(vert).all() and np.isfinite(normal).all() and np.isfinite(tex).all()):
        return None
    if corner_index.max() >= n:
        return None
    face = corner_index.astype(np.int32).reshape(-1, 3)
    tex[:, 1] = 1.0 - tex[:, 1]
    head = np.array([n, len(normal), len(tex), len(face)], dtype=np.int32)
    return b"".join(a.tobytes() for a in (head, vert, normal, tex, face))
