"""The decision being made: the stage's candidate targets, their certificate, and the
observer inferring which one the user is going for.

Every certificate is for one user: section 2's (``operator`` ``None``: the paper's user,
the certificate's model unclipped, as everywhere before operator models), or a person's
operator model (method.md §10; ``legws daemon --operator``), whose deflection the robot
clips: :func:`slack_for` and :func:`commit_for`.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from legws_daemon.core.certificate import certify
from legws_daemon.core.commit import CommitCertificate, certify_commit
from legws_daemon.core.geometry import FloatArray, Pose
from legws_daemon.core.goals import MIN_GOAL_DISTANCE, GoalSet
from legws_daemon.core.observer import IntentObserver
from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.hardware.base import RobotState
from legws_daemon.scene.scene import Layout, ObjectPose, Scene
from legws_daemon.task.runner import TaskRun
from legws_daemon.task.targets import Target, goal_set

#: A confirm with the EE this close to a candidate's grasp position acts on that candidate
#: (m; the simulated user confirms within 1 cm, ``joystick.sim_user.ARRIVED``).
CONFIRM_RADIUS = 0.03


def slack_for(goals: GoalSet, params: Params, operator: OperatorModel | None = None) -> float:
    """``J`` of ``goals`` for section 2's user (``operator`` ``None``), or for ``operator``
    with the robot's clip (``certify_with`` of an operator file)."""
    if operator is None:
        return certify(goals, params).objective
    return certify(goals, params, operator, operator.motion(params, clip=True)).objective


def commit_for(
    goals: GoalSet, params: Params, operator: OperatorModel | None = None
) -> CommitCertificate:
    """``K`` (method.md §9) of ``goals`` for section 2's user, or for ``operator`` with the
    robot's clip."""
    if operator is None:
        return certify_commit(goals, params)
    return certify_commit(goals, params, operator.motion(params, clip=True), operator=operator)


@dataclass
class StageState:
    """The stage being run: its candidate goals' poses and the layout they stand in.

    ``goals_home`` (the goal set seen from home) and ``certificate`` are ``None`` for a
    stage with a single candidate, which needs no inference. ``observed_certificate`` is
    the certificate recomputed from object poses a tracker reported (``None`` until then).
    """

    name: str
    targets: list[Target]
    layout: Layout
    certificate: float | None
    goals_home: GoalSet | None
    observed_certificate: float | None = None

    @classmethod
    def of(
        cls,
        task: TaskRun,
        layout: Layout,
        scene: Scene,
        params: Params,
        operator: OperatorModel | None = None,
    ) -> StageState:
        """The stage(s) ``task`` offers next, in ``layout``, certified from home (for
        ``operator``: :func:`slack_for`)."""
        targets = task.targets(layout) if not task.finished else []
        goals_home = cert = None
        if len(targets) >= 2:
            goals_home = goal_set(targets, scene.home)
            cert = slack_for(goals_home, params, operator)
        return cls(task.label, targets, dict(layout), cert, goals_home)

    @property
    def current_certificate(self) -> float | None:
        """What status reports: the observed certificate once there is one, else the plan's."""
        return self.certificate if self.observed_certificate is None else self.observed_certificate

    @property
    def goal_names(self) -> tuple[str, ...]:
        return tuple(t.name for t in self.targets)

    def target(self, goal: str) -> Target:
        for t in self.targets:
            if t.name == goal:
                return t
        raise KeyError(goal)


def decision_goals(task: TaskRun, layout: Mapping[str, ObjectPose], scene: Scene) -> GoalSet:
    """The targets of the decision ``task`` offers, in ``layout``, seen from home."""
    return goal_set(task.targets(layout), scene.home)


def certificate_of(
    task: TaskRun,
    layout: Mapping[str, ObjectPose],
    scene: Scene,
    params: Params,
    operator: OperatorModel | None = None,
) -> float:
    """``J`` of the decision ``task`` offers, its targets in ``layout``, seen from home (for
    ``operator``: :func:`slack_for`)."""
    return slack_for(decision_goals(task, layout, scene), params, operator)


class Inference:
    """The observer over a stage's targets, and the orientation teleoperation holds.

    What the observer watches: the EE's path (``from_input`` ``False``: where the EE moves
    at ``v_max · u``, the commit policy), or the operator's own input integrated from where
    the EE was when inference (re)started (:meth:`moved`: a policy that adds the robot's
    motion before the commit keeps the observer on the person's steering alone,
    docs/decisions.md).

    Args:
        params: observer parameters.
        dt: the control period, s.
        hold: the orientation to hold until the first restart (the home orientation).
        from_input: infer from the operator's integrated input instead of the EE's path.
    """

    def __init__(
        self, params: Params, dt: float, hold: FloatArray, from_input: bool = False
    ) -> None:
        self.params = params
        self.dt = dt
        self.observer: IntentObserver | None = None
        self.hold = hold
        self.from_input = from_input
        #: the operator's input integrated since the restart (``from_input``), m
        self.shadow: FloatArray | None = None
        self._first: int | None = None  # observer ticks before the first steering input

    def restart(self, stage: StageState, state: RobotState | None) -> None:
        """A fresh observer whose start pose is where the EE is now (from home when the
        state is unknown or the EE sits on a goal); teleoperation holds this orientation."""
        self._first = None
        if stage.goals_home is None:
            self.observer = None
            return
        goals = stage.goals_home
        if state is not None:
            self.hold = state.ee_rotation
            with contextlib.suppress(InputError):  # the EE sits on a goal: start from home
                # the same goals seen from the EE (their orientations converted once, off the
                # control loop when the stage was prepared)
                goals = dataclasses.replace(goals, x0=Pose(state.ee_position, state.ee_quaternion))
        self.observer = IntentObserver(goals, self.params)
        self.shadow = np.array(goals.x0.position, dtype=np.float64)

    def moved(self, velocity: FloatArray) -> None:
        """The operator's own motion this tick (``v_max · u``, clipped as the envelope
        clips the EE's), added to :attr:`shadow`."""
        if self.shadow is not None:
            self.shadow = self.shadow + np.asarray(velocity, dtype=np.float64) * self.dt

    def stop(self) -> None:
        self.observer = None
        self.shadow = None
        self._first = None

    def steered(self, axes: FloatArray) -> None:
        """This tick's input deflection (before :meth:`update`): the first non-zero one
        starts the clock of :attr:`seconds`."""
        if self._first is None and self.observer is not None and np.any(axes != 0.0):
            self._first = self.observer.ticks

    @property
    def seconds(self) -> float:
        """Seconds from the first steering input to now (0 before it): what the person
        spent steering until the commit, not the time the arm stood waiting for them."""
        if self.observer is None or self._first is None:
            return 0.0
        return (self.observer.ticks - self._first) * self.dt

    @property
    def waited(self) -> float:
        """Seconds the observer ran before the first steering input (all of it, if none)."""
        if self.observer is None:
            return 0.0
        first = self._first if self._first is not None else self.observer.ticks
        return first * self.dt

    def update(self, state: RobotState) -> tuple[str, float] | None:
        """One tick's EE pose; the goal committed to (posterior >= ``p_thresh``) and its
        probability, or ``None``."""
        obs = self.observer
        assert obs is not None
        here = self.shadow if self.from_input and self.shadow is not None else state.ee_position
        post = obs.update(here, state.ee_quaternion)
        if obs.committed is None:
            return None
        return obs.goals.names[obs.committed], float(post[obs.committed])

    def most_likely(self) -> tuple[str, float]:
        """The argmax goal and its probability."""
        obs = self.observer
        assert obs is not None
        best = int(np.argmax(obs.posterior))
        return obs.goals.names[best], float(obs.posterior[best])

    def confirmed(self, ee_position: FloatArray) -> tuple[str, float]:
        """What a press of *confirm* commits to, and its probability: the candidate whose
        grasp position the EE is within :data:`CONFIRM_RADIUS` of (the nearest) — the
        object the person has brought the hand to — else the most likely goal.

        With help before the commit the observer reads the operator's integrated input,
        which lags the EE the robot has moved; at the object its argmax can name a
        neighbour the hand is not at. Where the hand is names what the person vouches for.
        """
        obs = self.observer
        assert obs is not None
        d = np.linalg.norm(obs.goals.positions - np.asarray(ee_position), axis=1)
        at = int(np.argmin(d))
        if d[at] <= CONFIRM_RADIUS:
            return obs.goals.names[at], float(obs.posterior[at])
        return self.most_likely()

    def posterior(self) -> dict[str, float]:
        if self.observer is None:
            return {}
        names = self.observer.goals.names
        return dict(zip(names, (float(p) for p in self.observer.posterior), strict=True))


def live_slack(
    stage: StageState, state: RobotState, params: Params, operator: OperatorModel | None = None
) -> float | None:
    """The certificate seen from the EE pose ``state`` (how reliably intent can be read
    from there; for ``operator``: :func:`slack_for`), or ``None`` (no inference, or the EE
    sits on a goal)."""
    goals = stage.goals_home
    if goals is None:
        return None
    x0 = Pose(state.ee_position, state.ee_quaternion)
    if np.min(np.linalg.norm(goals.positions - x0.position, axis=1)) < 2 * MIN_GOAL_DISTANCE:
        return None
    live = GoalSet(goals.names, goals.positions, goals.quaternions, goals.symmetry, x0)
    return slack_for(live, params, operator)
