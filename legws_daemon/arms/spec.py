"""What legws knows about one arm: the robot description every part derives from.

Standard library only, and Python 3.8 at run time (annotations stay strings: no
subscripted builtin is evaluated): the bridges on a robot's own computer read
the same joint tables as the daemon (``bridge/``), so this module and the arm modules beside
it import nothing else.

Frames: scenes are in *table coordinates* (method.md §1: the frame the Sawyer's base
defines, the table top at ``workspace.table_height``). Each arm's base sits at its
:attr:`ArmSpec.mount` in that frame, so a scene, its layouts and its certificates mean the
same place on the table whatever arm stands at it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field


def yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """``[w, x, y, z]`` of a turn by ``yaw`` (rad) about the z axis: legws' one formula
    (:func:`legws_daemon.core.geometry.yaw_quat` is its array form)."""
    half = 0.5 * float(yaw)
    return (math.cos(half), 0.0, 0.0, math.sin(half))


@dataclass(frozen=True)
class Mount:
    """Where the arm's base stands in table coordinates: position (m) and yaw (rad)."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    yaw: float = 0.0

    def quaternion(self) -> tuple[float, float, float, float]:
        """``[w, x, y, z]`` of the yaw about the table's z axis."""
        return yaw_quaternion(self.yaw)


@dataclass(frozen=True)
class ArmSpec:
    """One arm. Joint vectors (limits, postures) have the arm's DoF, in joint order.

    Attributes:
        name: registry key (``sawyer``, ``panda``, ...): the profile's ``arm``, ``--robot``.
        title: what the arm is called in messages ("Rethink Sawyer").
        asset_folder: the folder of robosuite's wheel (``models/assets/robots/<folder>``)
            holding its ``robot.xml`` and meshes; cached under the assets folder as ``name``.
        joint_names: the MJCF joint names, base to wrist (also the names on the real arm's
            joint-state topic unless :attr:`hardware_joint_names` says otherwise).
        position_limits: ``(lower, upper)`` per joint, rad: the hardware's range (a
            continuous joint gets the range legws lets it use).
        speed_limits: per joint, rad/s (the manufacturer's specification).
        ready_posture: the posture the redundancy is pulled toward (keeps joints off their
            limits) and the first seed of the home pose's inverse kinematics.
        home_seeds: more seeds of the home pose's inverse kinematics.
        free_joints: joints the posture never pulls (the wrist roll follows the grasp yaw).
        hand_body: the MJCF body the gripper is mounted on (robosuite's ``right_hand``:
            z out of the flange).
        tcp_quat: the grasp frame (``ee`` site) in the hand's frame, ``[w, x, y, z]``: z
            the approach, x the closing direction.
        flange_yaw: the gripper's turn about the hand's z axis, rad (mounted so that the
            wrist's last joint is mid-range at the home pose).
        mount: the base's pose in table coordinates.
        mesh_collision_bodies: bodies whose *visual* meshes' convex hulls become their
            collision shapes (for a description whose collision shapes are coarse
            primitives, the Sawyer's); empty when the description ships collision meshes.
        primitive_bodies: more bodies whose primitive collision geoms the meshes replace.
        max_endpoint_speed: the guard's default cap on the endpoint's speed, m/s.
        min_reach: the nearest a grasp may be to the base's vertical axis, horizontally,
            m: nearer, the elbow folds against its limit and the straight approach stalls
            (measured per arm; the feasibility check and the reachability map refuse it).
        hardware_joint_names: the joint names of the real arm's interface, when they are
            not the MJCF's.
        model_xml: an MJCF given inline instead of the fetched folder (an arm described
            in code, e.g. a test's small arm; no mesh files).
    """

    name: str
    title: str
    asset_folder: str
    joint_names: tuple[str, ...]
    position_limits: tuple[tuple[float, float], ...]
    speed_limits: tuple[float, ...]
    ready_posture: tuple[float, ...]
    free_joints: tuple[int, ...]
    home_seeds: tuple[tuple[float, ...], ...] = ()
    hand_body: str = "right_hand"
    tcp_quat: tuple[float, float, float, float] = (math.sqrt(0.5), 0.0, 0.0, -math.sqrt(0.5))
    flange_yaw: float = 0.0
    mount: Mount = field(default_factory=Mount)
    mesh_collision_bodies: frozenset[str] = frozenset()
    primitive_bodies: frozenset[str] = frozenset()
    max_endpoint_speed: float = 0.25
    min_reach: float = 0.0
    hardware_joint_names: tuple[str, ...] | None = None
    model_xml: str | None = None

    def __post_init__(self) -> None:
        n = len(self.joint_names)
        if n < 6:
            raise ValueError(f"arm {self.name}: {n} joints, expected at least 6")
        for what, value in (
            ("position_limits", self.position_limits),
            ("speed_limits", self.speed_limits),
            ("ready_posture", self.ready_posture),
            *(("home_seeds", s) for s in self.home_seeds),
        ):
            if len(value) != n:
                raise ValueError(f"arm {self.name}: {what} has {len(value)} entries, expected {n}")
        for i, (lo, hi) in enumerate(self.position_limits):
            if not lo < hi:
                raise ValueError(f"arm {self.name}: joint {i} has an empty range")
            if not lo < self.ready_posture[i] < hi:
                raise ValueError(f"arm {self.name}: ready posture out of joint {i}'s range")
        if not all(v > 0 for v in self.speed_limits):
            raise ValueError(f"arm {self.name}: speed limits must be positive")
        if any(not 0 <= j < n for j in self.free_joints):
            raise ValueError(f"arm {self.name}: free_joints names a joint it does not have")
        if self.hardware_joint_names is not None and len(self.hardware_joint_names) != n:
            raise ValueError(f"arm {self.name}: hardware_joint_names must name {n} joints")

    def facts(self) -> dict:  # type: ignore[type-arg]
        """Everything the description says, JSON-ready (for the cache keys of what depends
        on the arm: maps, plans, optimisation runs); an inline model by its length only
        (its digest is the model's)."""
        out = asdict(self)
        out["model_xml"] = None if self.model_xml is None else len(self.model_xml)
        out["mesh_collision_bodies"] = sorted(self.mesh_collision_bodies)
        out["primitive_bodies"] = sorted(self.primitive_bodies)
        return out

    @property
    def dof(self) -> int:
        return len(self.joint_names)

    @property
    def prefix(self) -> str:
        """What the arm's MJCF names are prefixed with in a composed world."""
        return self.name + "/"

    @property
    def lower(self) -> tuple[float, ...]:
        return tuple(lo for lo, _ in self.position_limits)

    @property
    def upper(self) -> tuple[float, ...]:
        return tuple(hi for _, hi in self.position_limits)

    @property
    def hardware_joints(self) -> tuple[str, ...]:
        """The joint names the real arm's interface uses."""
        return self.hardware_joint_names or self.joint_names
