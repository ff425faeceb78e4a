"""What the arm looks like: its meshes per link, taken from the compiled MuJoCo model.

The Sawyer model (:mod:`legws_daemon.robot.assets`) is drawn from the same geometry that the
stand-in simulates: every visual geom (group 1) of a robot body, in that body's frame. The
meshes of one link are merged into one triangle mesh with per-vertex colours (the geom's
material colour) and smooth vertex normals, so a viewer gets one mesh per link; primitive
visual geoms (the gripper's base) are boxes; the two fingers are described apart, because
they move with the gripper's opening.

Links are numbered as :meth:`~legws_daemon.robot.world.World.link_poses` returns them (the
arm's bodies, base first), which is also the order of
:class:`~legws_daemon.hardware.base.LinkPoses` in every robot state: a drawing takes the
meshes once and the link poses every tick.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import mujoco
import numpy as np

from legws_daemon.arms import ArmSpec
from legws_daemon.core.geometry import FloatArray
from legws_daemon.robot.gripper import FINGER_GAP
from legws_daemon.robot.world import World, robot_model

#: Geom group of what is drawn (robot meshes and the gripper; see robot/world.py).
VISUAL_GROUP = 1
#: Names of the finger geoms on the hand (robot/world.py).
FINGER_GEOMS = ("finger_l", "finger_r")
HAND = "right_hand"
#: Half of the gap between the fingers' inner faces when the gripper is closed on nothing, m.
CLOSED_GAP = 0.004


@dataclass(frozen=True, slots=True)
class LinkMesh:
    """The merged visual meshes of one link, in the link's frame."""

    link: int  # index into the link poses
    name: str
    vertices: np.ndarray  # (N, 3) float32, m
    normals: np.ndarray  # (N, 3) float32, unit
    colors: np.ndarray  # (N,) uint32, 0xRRGGBBAA
    triangles: np.ndarray  # (M, 3) uint32


@dataclass(frozen=True, slots=True)
class LinkBox:
    """A box of a link (a primitive visual geom), in the link's frame."""

    link: int
    name: str
    center: FloatArray  # (3,)
    half_size: FloatArray  # (3,)
    quaternion: FloatArray  # (4,) [w, x, y, z]
    color: int  # 0xRRGGBBAA


@dataclass(frozen=True, slots=True)
class Fingers:
    """The gripper's two fingers as boxes on the hand link, moving along the hand's y axis."""

    link: int
    half_size: FloatArray  # (3,) in the hand frame
    z: float  # centre height along the hand's z, m
    color: int

    def centers(self, half_gap: float) -> FloatArray:
        """Centres ``(2, 3)`` of both fingers in the hand frame at a half-opening ``half_gap``
        (between the inner faces, m)."""
        y = float(half_gap) + float(self.half_size[1])
        return np.array([[0.0, y, self.z], [0.0, -y, self.z]])


@dataclass(frozen=True, slots=True)
class RobotVisual:
    """Everything drawn of the arm, per link."""

    links: tuple[str, ...]  # every link's name, in link-pose order (without the prefix)
    meshes: tuple[LinkMesh, ...]
    boxes: tuple[LinkBox, ...]
    fingers: Fingers | None

    @property
    def drawn_links(self) -> tuple[int, ...]:
        """The links that carry something to draw (their poses are needed each tick)."""
        found = {m.link for m in self.meshes} | {b.link for b in self.boxes}
        if self.fingers is not None:
            found.add(self.fingers.link)
        return tuple(sorted(found))

    @property
    def vertex_count(self) -> int:
        return sum(len(m.vertices) for m in self.meshes)


def finger_half_gap(closed: bool, held_width: float | None = None) -> float:
    """Half the opening between the fingers: open, closed on an object of ``held_width``
    (its extent along the closing axis, m), or closed on nothing."""
    if not closed:
        return FINGER_GAP
    if held_width is not None and np.isfinite(held_width) and held_width > 0:
        return float(min(FINGER_GAP, held_width / 2))
    return CLOSED_GAP


def _rgba(rgba: np.ndarray) -> int:
    r, g, b, a = (round(float(c) * 255) for c in np.clip(rgba, 0.0, 1.0))
    return (r << 24) | (g << 16) | (b << 8) | a


def _rotation(quat_wxyz: np.ndarray) -> FloatArray:
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat_wxyz, dtype=np.float64))
    return mat.reshape(3, 3)


def vertex_normals(vertices: FloatArray, triangles: np.ndarray) -> FloatArray:
    """Smooth unit normals ``(N, 3)``: the area-weighted mean of the faces around each vertex
    (a vertex of no face gets ``+z``)."""
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    faces = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    normals = np.zeros_like(v)
    for k in range(3):
        np.add.at(normals, t[:, k], faces)
    length = np.linalg.norm(normals, axis=1)
    normals[length == 0] = (0.0, 0.0, 1.0)
    length[length == 0] = 1.0
    out: FloatArray = normals / length[:, None]
    return out


def _geom_color(m: mujoco.MjModel, g: int) -> int:
    mat = int(m.geom_matid[g])
    return _rgba(m.mat_rgba[mat] if mat >= 0 else m.geom_rgba[g])


def _mesh_part(m: mujoco.MjModel, g: int) -> tuple[FloatArray, np.ndarray, int]:
    """Vertices (in the body frame), triangles and colour of one mesh geom."""
    mesh = int(m.geom_dataid[g])
    v0, nv = int(m.mesh_vertadr[mesh]), int(m.mesh_vertnum[mesh])
    f0, nf = int(m.mesh_faceadr[mesh]), int(m.mesh_facenum[mesh])
    local = np.asarray(m.mesh_vert[v0 : v0 + nv], dtype=np.float64)
    vertices = local @ _rotation(m.geom_quat[g]).T + m.geom_pos[g]
    return vertices, np.asarray(m.mesh_face[f0 : f0 + nf], dtype=np.int64), _geom_color(m, g)


def visual_of(m: mujoco.MjModel, link_bodies: list[int], prefix: str = "") -> RobotVisual:
    """The visual geometry of the given bodies (link ``i`` is ``link_bodies[i]``; names
    without ``prefix``)."""
    index = {body: i for i, body in enumerate(link_bodies)}
    names = tuple(m.body(b).name.removeprefix(prefix) for b in link_bodies)
    parts: dict[int, list[tuple[FloatArray, np.ndarray, int]]] = {}
    boxes: list[LinkBox] = []
    fingers: Fingers | None = None
    for g in range(m.ngeom):
        link = index.get(int(m.geom_bodyid[g]))
        if link is None or int(m.geom_group[g]) != VISUAL_GROUP:
            continue
        kind = int(m.geom_type[g])
        name = m.geom(g).name.removeprefix(prefix)
        if kind == mujoco.mjtGeom.mjGEOM_MESH:
            parts.setdefault(link, []).append(_mesh_part(m, g))
        elif kind == mujoco.mjtGeom.mjGEOM_BOX and name in FINGER_GEOMS:
            fingers = Fingers(link, np.array(m.geom_size[g]), float(m.geom_pos[g][2]),
                              _geom_color(m, g))  # fmt: skip
        elif kind == mujoco.mjtGeom.mjGEOM_BOX:
            boxes.append(LinkBox(link, name, np.array(m.geom_pos[g]), np.array(m.geom_size[g]),
                                 np.array(m.geom_quat[g]), _geom_color(m, g)))  # fmt: skip
    meshes = []
    for link in sorted(parts):
        vertices, triangles, colors, offset = [], [], [], 0
        for v, t, c in parts[link]:
            vertices.append(v)
            triangles.append(t + offset)
            colors.append(np.full(len(v), c, dtype=np.uint32))
            offset += len(v)
        v_all, t_all = np.concatenate(vertices), np.concatenate(triangles)
        meshes.append(
            LinkMesh(
                link,
                names[link],
                v_all.astype(np.float32),
                vertex_normals(v_all, t_all).astype(np.float32),
                np.concatenate(colors),
                t_all.astype(np.uint32),
            )
        )
    return RobotVisual(names, tuple(meshes), tuple(boxes), fingers)


@cache
def _visual_robot(spec: ArmSpec) -> RobotVisual:
    """The arm's visual geometry from the robot model alone (compiled once per process)."""
    m = robot_model(spec)
    return visual_of(m, list(range(1, m.nbody)))  # every body but the world, as World has them


def robot_visual(world: World) -> RobotVisual:
    """The visual geometry of ``world``'s arm, in its link-pose order.

    A world compiled without meshes (``visual=False``, the kinematic model of a real robot)
    borrows them from the robot model compiled on its own (once per process, ~1.5 s).
    """
    m = world.model
    links = [int(b) for b in world.link_ids]
    has_mesh = any(
        int(m.geom_bodyid[g]) in world.arm.robot_bodies
        and int(m.geom_type[g]) == mujoco.mjtGeom.mjGEOM_MESH
        for g in range(m.ngeom)
    )
    if has_mesh:
        return visual_of(m, links, world.prefix)
    alone = _visual_robot(world.spec)
    names = tuple(m.body(b).name.removeprefix(world.prefix) for b in links)
    if alone.links != names:  # not the same robot description
        return visual_of(m, links, world.prefix)
    return alone
