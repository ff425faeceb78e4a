"""A scene composed with ``MjSpec``: table, objects as primitive geometry, one arm.

World frame = table coordinates (method.md §1: the Sawyer's base frame): the table top at
``workspace.table_height``, its centre and size from the scene file; the arm (one of
:mod:`legws_daemon.arms`, the Sawyer by default) stands at its mount pose (the
Sawyer's at the origin). Every
object is a mocap body with one primitive geom matching its shape and size, so a layout is
applied without recompiling. A simple parallel gripper of primitive geoms is attached to
the hand; its ``ee`` site is the grasp frame convention of the grasp library (origin
between the fingertips, z the approach axis, x the closing direction).

Geom groups: 0 table and objects, 1 robot meshes and gripper, 3 robot collision
primitives (only without meshes; hidden in renders), 4 grasp markers.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import mujoco
import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.arms import DEFAULT_ARM, ArmSpec, arm
from legws_daemon.core.geometry import FloatArray, Pose, matrix_to_quat, yaw_quat
from legws_daemon.errors import InputError
from legws_daemon.robot.assets import RESTORE_COMMAND, arm_dir, verify
from legws_daemon.robot.gripper import FINGER_GAP, FINGER_HALF, TCP_OFFSET
from legws_daemon.scene.scene import ObjectPose, Scene

_GEOM = {
    "box": mujoco.mjtGeom.mjGEOM_BOX,
    "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
    "sphere": mujoco.mjtGeom.mjGEOM_SPHERE,
}


@dataclass(frozen=True, slots=True)
class ArmIndex:
    """Addresses of the arm in the compiled model."""

    qpos: np.ndarray  # (n,) qpos addresses, n the arm's DoF
    dof: np.ndarray  # (n,) dof addresses
    lower: FloatArray  # (n,) joint position limits (the arm description's)
    upper: FloatArray
    ee_site: int
    robot_bodies: frozenset[int]
    speed_limits: FloatArray  # (n,) rad/s


def _object_geom_size(shape: str, size: list[float]) -> list[float]:
    if shape == "box":
        return [size[0] / 2, size[1] / 2, size[2] / 2]
    if shape == "cylinder":
        return [size[0], size[1] / 2, 0.0]
    return [size[0], 0.0, 0.0]


def resolve_arm(which: ArmSpec | str) -> ArmSpec:
    """The arm named ``which`` (or ``which`` itself); one line naming the registered arms
    for a name that is not one."""
    if isinstance(which, ArmSpec):
        return which
    try:
        return arm(which)
    except KeyError as err:
        raise InputError(str(err.args[0])) from None


def _model_error(spec: ArmSpec, what: str, err: Exception) -> InputError:
    """One line for an arm's model that passed its integrity check but MuJoCo refuses."""
    detail = " ".join(str(err).split()) or type(err).__name__
    if spec.model_xml is not None:
        return InputError(f"MuJoCo cannot {what} the inline model of arm {spec.name} ({detail})")
    return InputError(
        f"MuJoCo cannot {what} the {spec.title} model ({detail}); "
        f"restore it with: {RESTORE_COMMAND}",
        source=str(arm_dir(None, spec.name) / "robot.xml"),
    )


def _robot_spec(spec: ArmSpec, visual: bool) -> mujoco.MjSpec:
    model = None
    try:
        if spec.model_xml is not None:
            robot = mujoco.MjSpec.from_string(spec.model_xml)
        else:
            model = verify(None, spec.name)
            robot = mujoco.MjSpec.from_file(str(model.folder / "robot.xml"))
    except (ValueError, mujoco.FatalError) as err:  # a bad XML, or a file it names
        raise _model_error(spec, "load", err) from None
    if visual and model is not None:
        for mesh in robot.meshes:  # the binary copies the fetch wrote: ~0.3 s less to load
            mesh.file = model.fast_mesh(mesh.file) or mesh.file
    for actuator in list(robot.actuators):
        robot.delete(actuator)
    for name, (lo, hi) in zip(spec.joint_names, spec.position_limits, strict=True):
        joint = robot.joint(name)
        if joint is None:
            raise _model_error(spec, "find the arm's joints in", KeyError(name))
        # the description's range (a continuous joint gets the one legws lets it use), so
        # MuJoCo, mink's limits and the bridges' guard hold the same numbers
        # (radians; in degrees for a model whose compiler reads angles in degrees)
        joint.range = np.degrees([lo, hi]) if robot.compiler.degree else [lo, hi]
        joint.limited = mujoco.mjtLimited.mjLIMITED_TRUE
    for geom in list(robot.geoms):
        body = geom.parent.name
        if geom.type == mujoco.mjtGeom.mjGEOM_MESH:
            collision_mesh = geom.contype != 0 or geom.conaffinity != 0
            if not visual:
                robot.delete(geom)
            elif body in spec.mesh_collision_bodies:
                # the visual meshes' convex hulls are these links' collision shapes
                geom.contype, geom.conaffinity = 1, 1
            elif collision_mesh:  # a description's own collision mesh: hidden in renders
                geom.group, geom.contype, geom.conaffinity = 3, 1, 1
        elif visual and (body in spec.mesh_collision_bodies or body in spec.primitive_bodies):
            robot.delete(geom)
        else:
            geom.group = 3  # collision primitives: hidden in renders
    if not visual:
        for mesh in list(robot.meshes):
            robot.delete(mesh)
        for material in list(robot.materials):
            robot.delete(material)
    hand = robot.body(spec.hand_body)
    if hand is None:
        raise _model_error(spec, "find the hand body in", KeyError(spec.hand_body))
    if spec.flange_yaw:  # the gripper turned on the flange (puts the wrist mid-range at home)
        hand = hand.add_body(name="gripper", quat=list(yaw_quat(spec.flange_yaw)))
    grey = [0.25, 0.25, 0.27, 1.0]
    hand.add_geom(
        name="gripper_base", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.02, 0.055, 0.03],
        pos=[0, 0, 0.03], rgba=grey, group=1,
    )  # fmt: skip
    hx, hy, hz = FINGER_HALF  # in the ee frame: hand y is the closing direction
    for side, y in (("l", 1.0), ("r", -1.0)):
        # fingers end at the grasp point (the TCP), so fingertips never pass below it
        hand.add_geom(
            name=f"finger_{side}", type=mujoco.mjtGeom.mjGEOM_BOX, size=[hy, hx, hz],
            pos=[0, y * (FINGER_GAP + hx), TCP_OFFSET - hz], rgba=[0.1, 0.1, 0.1, 1.0],
            group=1,
        )  # fmt: skip
    # site frame: z along the hand's z (approach), x the closing direction (the arm's
    # ``tcp_quat``; for the Sawyer the hand's -y, which puts the wrist roll mid-range at the
    # home pose)
    hand.add_site(
        name="ee", pos=[0, 0, TCP_OFFSET], quat=list(spec.tcp_quat), size=[0.008, 0, 0],
        group=4,
    )  # fmt: skip
    return robot


def robot_model(which: ArmSpec | str = DEFAULT_ARM) -> mujoco.MjModel:
    """The robot alone, with its meshes and the gripper, compiled (~0.3 s): its bodies are
    the arm's links in the order a :class:`World` has them, without the prefix."""
    spec = resolve_arm(which)
    try:
        return _robot_spec(spec, visual=True).compile()
    except (ValueError, mujoco.FatalError) as err:
        raise _model_error(spec, "compile", err) from None


class World:
    """A compiled scene with one arm, and the arm's state.

    Args:
        scene: the scene (objects, workspace, home pose).
        arm: the arm (a registered name or its description; default the Sawyer).
        visual: with the robot's meshes (default), which are drawn and whose convex hulls
            are its collision shapes. Without them the model compiles ~25x faster (20 ms)
            and kinematics is the same, but collisions use the robot description's coarse
            primitives, which are conservative (low side grasps hit the table).
        decorate: called with the composed ``MjSpec`` just before it is compiled, to add
            what only a picture needs (e.g. the tracker's textured marker decals, which
            must not collide: ``contype = conaffinity = 0``).
    """

    def __init__(
        self,
        scene: Scene,
        *,
        arm: ArmSpec | str = DEFAULT_ARM,
        visual: bool = True,
        decorate: Callable[[mujoco.MjSpec], None] | None = None,
    ) -> None:
        self.scene = scene
        self.spec = resolve_arm(arm)
        prefix = self.prefix = self.spec.prefix
        spec = mujoco.MjSpec()
        spec.modelname = f"legws_{scene.name}"
        spec.option.timestep = 0.002
        spec.visual.global_.offwidth = 1280
        spec.visual.global_.offheight = 960
        ws = scene.workspace
        table = spec.worldbody.add_body(
            name="table",
            pos=[ws.table_center[0], ws.table_center[1], ws.table_height - 0.02],
        )
        table.add_geom(
            name="table_top",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[ws.table_size[0] / 2, ws.table_size[1] / 2, 0.02],
            rgba=[0.82, 0.74, 0.6, 1.0],
        )
        spec.worldbody.add_light(pos=[0.6, 0.0, 2.5], dir=[0, 0, -1], diffuse=[0.8, 0.8, 0.8])
        poses = scene.poses()
        for name, obj in scene.objects.items():
            body = spec.worldbody.add_body(name=f"obj/{name}", mocap=True)
            p = poses[name]
            body.pos = [p.x, p.y, scene.z_center(name)]
            body.quat = yaw_quat(p.yaw)
            body.add_geom(
                name=f"obj/{name}",
                type=_GEOM[obj.shape],
                size=_object_geom_size(obj.shape, list(obj.size)),
                rgba=[*obj.color, 1.0],
            )
        mount = self.spec.mount
        frame = spec.worldbody.add_frame(
            pos=[mount.x, mount.y, mount.z], quat=list(mount.quaternion())
        )
        spec.attach(_robot_spec(self.spec, visual), prefix=prefix, frame=frame)
        if decorate is not None:
            decorate(spec)
        try:
            self.model = spec.compile()
        except (ValueError, mujoco.FatalError) as err:  # e.g. a mesh it cannot read
            raise _model_error(self.spec, "compile", err) from None
        self.data = mujoco.MjData(self.model)
        m = self.model
        try:
            joints = [m.joint(prefix + j) for j in self.spec.joint_names]
            ee_site = m.site(prefix + "ee").id
        except KeyError as err:  # a robot.xml without the arm's joints
            raise _model_error(self.spec, "find the arm's joints in", err) from None
        robot_bodies = frozenset(b for b in range(m.nbody) if m.body(b).name.startswith(prefix))
        self.arm = ArmIndex(
            qpos=np.array([j.qposadr[0] for j in joints]),
            dof=np.array([j.dofadr[0] for j in joints]),
            lower=np.array(self.spec.lower),
            upper=np.array(self.spec.upper),
            ee_site=ee_site,
            robot_bodies=robot_bodies,
            speed_limits=np.array(self.spec.speed_limits),
        )
        self.dof = self.spec.dof
        self._mocap = {
            name: int(m.body_mocapid[m.body(f"obj/{name}").id]) for name in scene.objects
        }
        self._object_of_body = {m.body(f"obj/{n}").id: n for n in scene.objects}
        self._link_ids = np.array(sorted(robot_bodies))
        self._jacp = np.zeros((3, m.nv))
        self._jacr = np.zeros((3, m.nv))
        # the arm's dofs are the model's only dofs, in order: plain slices, no fancy indexing
        dof = self.arm.dof
        self._dof = slice(int(dof[0]), int(dof[-1]) + 1)
        qadr = self.arm.qpos
        self._qslice = slice(int(qadr[0]), int(qadr[-1]) + 1)
        assert np.array_equal(dof, np.arange(dof[0], dof[-1] + 1))
        assert np.array_equal(qadr, np.arange(qadr[0], qadr[-1] + 1))
        mujoco.mj_forward(m, self.data)

    def twin(self) -> World:
        """Another arm and layout state on the same compiled model (its own ``MjData``,
        starting where this one is): to plan, check or draw without moving this one.
        Cheap: nothing is compiled again."""
        other = copy.copy(self)
        other.data = mujoco.MjData(self.model)
        other.data.qpos[:] = self.data.qpos
        other.data.mocap_pos[:] = self.data.mocap_pos
        other.data.mocap_quat[:] = self.data.mocap_quat
        other._jacp = np.zeros_like(self._jacp)
        other._jacr = np.zeros_like(self._jacr)
        mujoco.mj_forward(self.model, other.data)
        return other

    # --- layout -------------------------------------------------------------------
    def set_layout(self, layout: Mapping[str, ObjectPose]) -> None:
        """Move the named objects (others keep their pose); kinematics is updated."""
        for name, p in layout.items():
            i = self._mocap[name]
            self.data.mocap_pos[i] = [p.x, p.y, self.scene.z_center(name)]
            self.data.mocap_quat[i] = yaw_quat(p.yaw)
        mujoco.mj_kinematics(self.model, self.data)

    def object_pose(self, name: str) -> tuple[FloatArray, FloatArray]:
        """Position and quaternion ``[w, x, y, z]`` of an object's body."""
        i = self._mocap[name]
        return np.array(self.data.mocap_pos[i]), np.array(self.data.mocap_quat[i])

    def set_object_pose(self, name: str, position: ArrayLike, quaternion: ArrayLike) -> None:
        """Move one object freely (e.g. while it is held); kinematics is not updated."""
        i = self._mocap[name]
        self.data.mocap_pos[i] = position
        self.data.mocap_quat[i] = quaternion

    # --- arm state ----------------------------------------------------------------
    @property
    def q(self) -> FloatArray:
        return np.array(self.data.qpos[self._qslice])

    def set_q(self, q: ArrayLike) -> None:
        """Set the arm's joint positions and update kinematics (no dynamics)."""
        self.data.qpos[self._qslice] = q
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)

    def ee_position(self) -> FloatArray:
        return np.array(self.data.site_xpos[self.arm.ee_site])

    def ee_rotation(self) -> FloatArray:
        """The EE orientation (3, 3): a copy (MuJoCo's buffer changes with the arm)."""
        return np.array(self.data.site_xmat[self.arm.ee_site], dtype=np.float64).reshape(3, 3)

    def ee_pose(self) -> Pose:
        return Pose(self.ee_position(), matrix_to_quat(self.ee_rotation()))

    def link_poses(self, q: ArrayLike | None = None) -> tuple[FloatArray, FloatArray]:
        """Origins ``(K, 3)`` and rotations ``(K, 3, 3)`` of the arm's bodies, base first
        (at ``q`` if given — the arm is then left there — else at the current state)."""
        if q is not None:
            self.set_q(q)
        ids = self._link_ids
        return np.array(self.data.xpos[ids]), np.array(self.data.xmat[ids]).reshape(-1, 3, 3)

    @property
    def link_ids(self) -> np.ndarray:
        """Body ids of the arm's links, in the order of :meth:`link_poses`."""
        return self._link_ids

    def jacobian(self) -> FloatArray:
        """``(6, n)`` EE Jacobian (``n`` the arm's DoF): linear rows then angular rows,
        world frame."""
        mujoco.mj_jacSite(self.model, self.data, self._jacp, self._jacr, self.arm.ee_site)
        J = np.empty((6, self.dof))
        J[:3] = self._jacp[:, self._dof]
        J[3:] = self._jacr[:, self._dof]
        return J

    # --- collisions ---------------------------------------------------------------
    def arm_contacts(self, ignore: frozenset[str] = frozenset()) -> list[tuple[str, str]]:
        """Contacts between the robot and the table or objects (not in ``ignore``).

        Returns ``(robot geom, other)`` pairs; ``other`` is ``table`` or an object name.
        """
        m, d = self.model, self.data
        mujoco.mj_forward(m, d)
        hits: list[tuple[str, str]] = []
        for c in d.contact[: d.ncon]:
            b1, b2 = int(m.geom_bodyid[c.geom1]), int(m.geom_bodyid[c.geom2])
            r1, r2 = b1 in self.arm.robot_bodies, b2 in self.arm.robot_bodies
            if r1 == r2:
                continue
            robot_geom, other_body = (c.geom1, b2) if r1 else (c.geom2, b1)
            other = self._object_of_body.get(other_body, m.body(other_body).name)
            if other in ignore or c.dist > 0:
                continue
            part = m.geom(robot_geom).name or m.body(m.geom_bodyid[robot_geom]).name
            hits.append((part.removeprefix(self.prefix), other))
        return hits
