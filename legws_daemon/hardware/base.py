"""The adapter interface and its registry (name -> class, no if/elif factory).

An adapter connects to one robot, reports its state, and sends EE velocity or joint
velocity commands. Every command passes through the safety envelope
(:mod:`legws_daemon.safety.envelope`) inside :meth:`Adapter.send_velocity` and
:meth:`Adapter.send_joint_velocity`, which return what was actually sent.

Every public method of :class:`Adapter` is final: it runs the subclass's hook (``connect``
runs ``_connect``, ``read_state`` ``_read_state``, ``send_velocity`` the envelope then
``_command``, ...) inside one guard, which turns anything but a
:class:`~legws_daemon.errors.LegwsError` into a :class:`~legws_daemon.errors.HardwareError`
naming the call. A subclass that defines one of the public methods is refused when the
class is made, so no call reaches the robot around the guard.
"""

from __future__ import annotations

import logging
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any, ClassVar, TypeVar, final

import numpy as np
import zenoh

from legws_daemon.core.geometry import FloatArray, matrix_to_quat
from legws_daemon.errors import HardwareError, InputError, LegwsError
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.robot.gripper import floor_height
from legws_daemon.robot.kinematics import LIMIT_MARGIN
from legws_daemon.robot.world import World, resolve_arm
from legws_daemon.safety.envelope import (
    Box,
    clamp_ee_velocity,
    clamp_joint_velocity,
    limit_ee_speed,
)
from legws_daemon.scene.scene import ObjectPose, Scene


@dataclass(frozen=True, slots=True)
class LinkPoses:
    """Where the arm's bodies are, base first: origins ``(K, 3)``, rotations ``(K, 3, 3)``."""

    positions: FloatArray
    rotations: FloatArray


@dataclass(frozen=True, slots=True)
class RobotState:
    """What the robot reports, read once per tick: joint positions, the EE pose from the
    kinematic model (rotation and quaternion), the arm's link poses, and when it was
    measured."""

    q: FloatArray  # (7,) rad
    ee_position: FloatArray  # (3,) m
    ee_rotation: FloatArray  # (3, 3)
    stamp: float  # monotonic seconds of the measurement
    links: LinkPoses
    gripper_closed: bool = False
    #: the robot side holds a stop from this role (no motion until :meth:`Adapter.resume`)
    stopped_by: str | None = None
    ee_quaternion: FloatArray = field(init=False)  # (4,) [w, x, y, z]

    def __post_init__(self) -> None:
        object.__setattr__(self, "ee_quaternion", matrix_to_quat(self.ee_rotation))


def model_state(
    model: World, stamp: float, gripper_closed: bool, stopped_by: str | None = None
) -> RobotState:
    """The state of a kinematic model at its current configuration."""
    positions, rotations = model.link_poses()
    return RobotState(
        model.q, model.ee_position(), model.ee_rotation(), stamp,
        LinkPoses(positions, rotations), gripper_closed, stopped_by,
    )  # fmt: skip


@dataclass(frozen=True, slots=True)
class JointCommand:
    """What :meth:`Adapter.send_joint_velocity` sent: the joint velocities (rad/s) and the
    EE's linear velocity they make, to first order (m/s)."""

    qdot: FloatArray
    ee_velocity: FloatArray


log = logging.getLogger("legws.hardware")
_T = TypeVar("_T")

#: Joint-space moves keep the EE's turning rate below this, rad/s.
MAX_EE_ANGULAR_SPEED = 0.8
#: Bisection steps cutting a joint step that would leave the workspace box.
BOX_BISECTIONS = 16


class Adapter(ABC):
    """A robot reached through a hardware profile.

    Every adapter is built the same way, so the daemon picks one from the registry by the
    profile's ``adapter`` name. The control loop reads the state once per tick
    (:meth:`read_state`) and hands that state to the command it sends
    (:meth:`send_velocity` or :meth:`send_joint_velocity`), which clamps the command to
    the safety envelope and returns what was actually sent.

    The envelope is the profile's workspace box with a floor that keeps the fingertips
    :data:`~legws_daemon.robot.gripper.FINGERTIP_CLEARANCE` above the table at the EE's
    orientation; a move may lower that floor to its own target (the final approach of a
    grasp), never below the box.

    Subclasses implement the hooks (``_connect``, ``_disconnect``, ``_read_state``,
    ``_kinematics``, ``_command``, ``_command_joints``, ``_grip``, ``_halt``, and where
    they differ from the stand-in's ``_stop_by``, ``_paused``, ``_resume``,
    ``_object_poses``, ``_place_objects``); the public methods are final (see the module
    docstring): adapters raise :class:`~legws_daemon.errors.LegwsError` for what they
    expect (a lost heartbeat, a refused command), and anything else (a bug, a library
    error) — which would otherwise end the loop with the robot's last command still live
    on the robot side — becomes a :class:`~legws_daemon.errors.HardwareError` naming the
    call, so the controller stops the robot and reports a ``fault`` like any other. The
    first traceback of each kind is logged.

    Args:
        profile: the hardware profile (rates, limits, workspace box, adapter settings).
        scene: the scene around the robot (the stand-in builds its world from it; a real
            robot's adapter uses it for the kinematic model's table and objects).
        session: the daemon's open zenoh session (adapters that talk to a robot-side
            bridge need it; the stand-in does not).
    """

    def __init__(
        self, profile: ProfileSpec, scene: Scene, session: zenoh.Session | None = None
    ) -> None:
        self.profile = profile
        self.scene = scene
        self.session = session
        self.box = Box.of(profile.workspace)
        self.dt = 1.0 / profile.control.rate_hz
        self.v_max = max(profile.control.v_max, profile.control.assist_speed)
        #: joint speeds at most (rad/s): the specification's, capped as the bridge caps them
        self.speed_limits = np.minimum(
            np.asarray(resolve_arm(profile.arm).speed_limits, dtype=np.float64),
            profile.bridge.joint_speed_cap,
        )
        self.w_max = MAX_EE_ANGULAR_SPEED
        self.table_height = scene.workspace.table_height
        self._logged: set[tuple[str, str]] = set()

    #: the public methods, each the guarded way to its hook, and the envelope's own steps
    #: (subclasses define none of them)
    FINAL: ClassVar[frozenset[str]] = frozenset(
        {
            "connect", "disconnect", "read_state", "kinematics", "send_velocity",
            "send_joint_velocity", "grip", "halt", "stop_by", "paused", "resume",
            "object_poses", "place_objects", "stop", "envelope", "_guard",
            "_send_velocity", "_send_joint_velocity",
        }
    )  # fmt: skip

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        bypass = sorted(Adapter.FINAL & set(vars(cls)))
        if bypass:
            raise TypeError(
                f"{cls.__name__} defines {', '.join(bypass)}: an adapter implements the "
                "hooks (_connect, _read_state, ...); the public methods are the guard's"
            )

    def _guard(self, what: str, fn: Callable[..., _T], *args: Any) -> _T:
        """``fn(*args)``; anything it raises but a :class:`LegwsError` is a
        :class:`HardwareError` naming ``what`` (its first traceback of a kind logged)."""
        try:
            return fn(*args)
        except LegwsError:
            raise
        except Exception as err:
            key = (what, type(err).__name__)
            if key not in self._logged:
                self._logged.add(key)
                log.error("adapter %s raised %s", what, type(err).__name__, exc_info=True)
            raise HardwareError(f"{what}: {type(err).__name__}: {err}") from err

    # --- the public, guarded methods --------------------------------------------------
    @final
    def connect(self) -> None:
        """Open the connection; raise a :class:`~legws_daemon.errors.LegwsError` on failure."""
        self._guard("connect", self._connect)

    @final
    def disconnect(self) -> None:
        """Stop the robot and close the connection (idempotent)."""
        self._guard("disconnect", self._disconnect)

    @final
    def read_state(self) -> RobotState:
        """The latest measured state."""
        return self._guard("read_state", self._read_state)

    @final
    @property
    def kinematics(self) -> World:
        """The robot's kinematic model (connected adapters only): the envelope predicts
        joint steps with it, the motion planner plans on a twin of it."""
        return self._guard("kinematics", self._kinematics)

    @final
    def grip(self, closed: bool) -> None:
        """Close (``True``) or open the gripper."""
        self._guard("grip", self._grip, closed)

    @final
    def halt(self) -> None:
        """Command zero velocity now, without a state (the state may be what failed)."""
        self._guard("halt", self._halt)

    @final
    def stop_by(self, by: str) -> None:
        """A stop from ``by`` (a role): halt now and tell the robot side, which holds the
        stop until :meth:`resume`."""
        self._guard("stop_by", self._stop_by, by)

    @final
    def paused(self, resumed: float) -> None:
        """The daemon stood still until ``resumed`` (monotonic s; the process was paused):
        an adapter that judges the robot side by what it heard measures its silence from
        then — nothing was heard while the daemon did not run."""
        self._guard("paused", self._paused, resumed)

    @final
    def resume(self) -> None:
        """Clear the robot side's stop (or a latched implausible state) before a reset.

        Raises:
            HardwareError: the robot side still holds its stop.
        """
        self._guard("resume", self._resume)

    @final
    def object_poses(self) -> dict[str, tuple[FloatArray, FloatArray]]:
        """Measured object poses, name -> (position, quaternion ``[w, x, y, z]``).

        Empty when the adapter cannot see objects (a real robot: a tracker reports them on
        ``legws/<robot>/objects``).
        """
        return self._guard("object_poses", self._object_poses)

    @final
    def place_objects(self, layout: Mapping[str, ObjectPose]) -> bool:
        """Put objects at ``layout``; ``False`` when a person has to (a real robot)."""
        return bool(self._guard("place_objects", self._place_objects, layout))

    # --- the hooks ----------------------------------------------------------------------
    @abstractmethod
    def _connect(self) -> None:
        """Open the connection (:meth:`connect`)."""

    @abstractmethod
    def _disconnect(self) -> None:
        """Stop the robot and close the connection, idempotent (:meth:`disconnect`)."""

    @abstractmethod
    def _read_state(self) -> RobotState:
        """The latest measured state (:meth:`read_state`)."""

    @abstractmethod
    def _kinematics(self) -> World:
        """The robot's kinematic model (:attr:`kinematics`)."""

    @abstractmethod
    def _command(
        self, state: RobotState, velocity: FloatArray, hold: FloatArray | None, box: Box
    ) -> None:
        """Apply an already clamped EE velocity for one control period, from ``state``;
        the EE must not leave ``box`` (the envelope the velocity was clamped to)."""

    @abstractmethod
    def _command_joints(self, state: RobotState, qdot: FloatArray) -> None:
        """Apply already clamped joint velocities for one control period, from ``state``."""

    @abstractmethod
    def _grip(self, closed: bool) -> None:
        """Close (``True``) or open the gripper (:meth:`grip`)."""

    @abstractmethod
    def _halt(self) -> None:
        """Command zero velocity now, without a state (:meth:`halt`)."""

    def _stop_by(self, by: str) -> None:
        """:meth:`stop_by` (the stand-in has no robot side: halting is all)."""
        self._halt()

    def _paused(self, resumed: float) -> None:
        """:meth:`paused` (the stand-in hears nothing)."""
        return

    def _resume(self) -> None:
        """:meth:`resume` (the stand-in holds no stop)."""
        return

    def _object_poses(self) -> dict[str, tuple[FloatArray, FloatArray]]:
        """:meth:`object_poses` (none: the adapter cannot see objects)."""
        return {}

    def _place_objects(self, layout: Mapping[str, ObjectPose]) -> bool:
        """:meth:`place_objects` (``False``: a person has to)."""
        return False

    def envelope(self, rotation: FloatArray, floor: float | None = None) -> Box:
        """The workspace box with the fingertip floor for the EE orientation ``rotation``
        (lowered to ``floor`` for a final approach, never below the box)."""
        z = floor_height(rotation, self.table_height)
        if floor is not None:
            z = min(z, floor)
        return self.box.with_floor(z)

    @final
    def send_velocity(
        self,
        state: RobotState,
        velocity: object,
        hold: FloatArray | None = None,
        floor: float | None = None,
    ) -> FloatArray:
        """Clamp ``velocity`` to the safety envelope at ``state``, send it, return what
        was sent.

        Args:
            state: this tick's state (read once, by the caller).
            velocity: requested EE linear velocity (3,), m/s; anything invalid sends zero.
            hold: EE orientation (3, 3) to hold, or ``None`` for the current one.
            floor: the lowest EE height this command may reach (a final approach), m.
        """
        return self._guard("send_velocity", self._send_velocity, state, velocity, hold, floor)

    def _send_velocity(
        self, state: RobotState, velocity: object, hold: FloatArray | None, floor: float | None
    ) -> FloatArray:
        box = self.envelope(state.ee_rotation, floor)
        sent = clamp_ee_velocity(state.ee_position, velocity, self.dt, box, self.v_max)
        self._command(state, sent, hold, box)
        return sent

    @final
    def send_joint_velocity(
        self, state: RobotState, qdot: object, floor: float | None = None
    ) -> JointCommand:
        """Clamp joint velocities (joint speed and position limits, EE speed at most
        ``v_max``, turning at most ``w_max``, the EE inside the envelope), send them,
        return what was sent.

        Args:
            state: this tick's state.
            qdot: requested joint velocities (7,), rad/s; anything invalid sends zero.
            floor: the lowest EE height this command may reach, m.
        """
        return self._guard("send_joint_velocity", self._send_joint_velocity, state, qdot, floor)

    def _send_joint_velocity(
        self, state: RobotState, qdot: object, floor: float | None
    ) -> JointCommand:
        model = self.kinematics
        arm = model.arm
        qd = clamp_joint_velocity(
            state.q, qdot, self.dt, arm.lower + LIMIT_MARGIN, arm.upper - LIMIT_MARGIN,
            self.speed_limits,
        )  # fmt: skip
        ee_velocity = np.zeros(3)
        if qd.any():
            if not np.array_equal(model.q, state.q):
                model.set_q(state.q)  # (the adapter's model is usually there: it was read)
            J = model.jacobian()
            qd = limit_ee_speed(J, qd, self.v_max, self.w_max)
            qd = self._joint_step_in_envelope(model, state, qd, floor)
            ee_velocity = J[:3] @ qd
        self._command_joints(state, qd)
        return JointCommand(qd, ee_velocity)

    def _joint_step_in_envelope(
        self, model: World, state: RobotState, qdot: FloatArray, floor: float | None
    ) -> FloatArray:
        """``qdot`` shortened (same direction) so that the step ends with the EE no further
        outside the envelope, on any axis, than it is now (inside: not outside at all)."""
        box0 = self.envelope(state.ee_rotation, floor)
        p0 = state.ee_position
        allowed = np.maximum(np.maximum(box0.lower - p0, p0 - box0.upper), 0.0)

        def fits(fraction: float) -> bool:
            model.set_q(state.q + fraction * qdot * self.dt)
            p = model.ee_position()
            box = self.envelope(model.ee_rotation(), floor)
            return bool(np.all(np.maximum(box.lower - p, p - box.upper) <= allowed + 1e-9))

        if fits(1.0):
            return qdot
        good, bad = 0.0, 1.0
        for _ in range(BOX_BISECTIONS):
            mid = 0.5 * (good + bad)
            if fits(mid):
                good = mid
            else:
                bad = mid
        return qdot * good

    @final
    def stop(self) -> FloatArray:
        """Send zero velocity from a freshly read state."""
        return self.send_velocity(self.read_state(), np.zeros(3))

    def __enter__(self) -> Adapter:
        self.connect()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.disconnect()


_REGISTRY: dict[str, type[Adapter]] = {}


def register(name: str) -> Callable[[type[Adapter]], type[Adapter]]:
    """Class decorator: make an adapter available under ``name``."""

    def add(cls: type[Adapter]) -> type[Adapter]:
        if name in _REGISTRY:
            raise ValueError(f"adapter '{name}' is registered twice")
        _REGISTRY[name] = cls
        return cls

    return add


def adapter_class(name: str) -> type[Adapter]:
    """The adapter registered under ``name``; unknown names list the known ones."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise InputError(
            f"unknown adapter '{name}'; known: {', '.join(sorted(_REGISTRY))}", field="adapter"
        ) from None
