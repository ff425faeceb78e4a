"""What the daemon tells the world: typed event records, serialised in one place.

Every event is a frozen dataclass whose fields are its ``detail`` on
``legws/<robot>/events`` (docs/messages.md); :meth:`Event.detail` is the only place that
turns one into the wire form, :meth:`Event.text` the only place that writes its log line.
``warning`` events come in several shapes, one class each.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

import numpy as np

from legws_daemon.autonomy.placing import verdict
from legws_daemon.formats.log_lines import How, commit_text, reach_text, reached_text
from legws_daemon.formats.messages import EventKind


def jsonable(value: Any) -> Any:
    """``value`` with numpy arrays and scalars, tuples and non-string keys made JSON-ready."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


@dataclass(frozen=True, slots=True)
class Event:
    """An event; subclasses set :attr:`kind` and declare the detail's fields."""

    kind: ClassVar[EventKind]

    def detail(self) -> dict[str, Any]:
        """The wire ``detail``: every field, JSON-ready."""
        return {f.name: jsonable(getattr(self, f.name)) for f in fields(self)}

    def text(self) -> str:
        """One log line: the kind and the detail's fields (``key=value``)."""
        parts = " ".join(f"{k}={v}" for k, v in self.detail().items())
        return f"{self.kind} {parts}".strip()


#: Receives events (the daemon publishes and logs them; ``legws eval`` reads them).
Emit = Callable[[Event], None]


# --- the run -------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Started(Event):
    """The daemon runs: ``certificate`` is the first decision's, for ``operator_model``
    (``{"name", "model"}`` of the operator file, ``None``: section 2's user)."""

    kind: ClassVar[EventKind] = "started"
    adapter: str
    scene: str
    task: str
    stage: str
    certificate: float | None
    operator_model: dict[str, Any] | None = None


@dataclass(frozen=True, slots=True)
class Loaded(Event):
    kind: ClassVar[EventKind] = "loaded"
    scene: str
    task: str
    stage: str
    certificate: float | None


@dataclass(frozen=True, slots=True)
class Shutdown(Event):
    kind: ClassVar[EventKind] = "shutdown"
    ticks: int
    overruns: int


@dataclass(frozen=True, slots=True)
class Fallback(Event):
    kind: ClassVar[EventKind] = "fallback"
    reason: str
    adapter: str
    note: str = "falling back"


# --- inference and assistance ----------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Commit(Event):
    """The robot acts on ``goal``: inferred (``p >= p_thresh``), ``confirmed`` by the
    button, or ``single`` (one candidate, no inference)."""

    kind: ClassVar[EventKind] = "commit"
    goal: str
    p: float
    tick: int
    seconds: float  # from the first steering input of this decision to the commit
    waited: float  # inference before that input (the person had not steered yet)
    stage: str
    decision: str
    action: str
    confirmed: bool
    single: bool
    certificate: float | None
    posterior: dict[str, float] = field(default_factory=dict)

    def detail(self) -> dict[str, Any]:
        d = Event.detail(self)
        d["p"], d["seconds"] = round(self.p, 4), round(self.seconds, 3)
        d["waited"] = round(self.waited, 3)
        return d

    def text(self) -> str:
        how: How = "single" if self.single else "confirmed" if self.confirmed else "inferred"
        return commit_text(self.goal, round(self.p, 4), how=how)


@dataclass(frozen=True, slots=True)
class Cancel(Event):
    kind: ClassVar[EventKind] = "cancel"
    reason: str  # button | opposed
    goal: str
    phase: str


@dataclass(frozen=True, slots=True)
class Override(Event):
    """The operator held the stick against the goal the robot moved toward
    (:mod:`.override`): control is theirs again, inference restarted from here.
    ``during``: ``assist`` (the committed goal's plan, dropped; ``phase`` its step) or
    ``blend`` (the guess before the commit: the robot stops helping toward it until
    inference guesses another goal)."""

    kind: ClassVar[EventKind] = "override"
    goal: str
    during: str  # assist | blend
    phase: str | None = None


@dataclass(frozen=True, slots=True)
class StageDone(Event):
    kind: ClassVar[EventKind] = "stage_done"
    stage: str
    goal: str
    action: str
    ticks: int
    cancelled: bool = False  # given back after the gripper acted: the stage counts as done


@dataclass(frozen=True, slots=True)
class TaskDone(Event):
    kind: ClassVar[EventKind] = "task_done"
    task: str
    history: tuple[tuple[str, str], ...]  # (stage, goal) in order


# --- calibration (legws operator calibrate) -----------------------------------------------
@dataclass(frozen=True, slots=True)
class CalibrationReach(Event):
    """A calibration target appears: reach ``reach`` of ``of`` toward ``target`` (m, base
    frame), ``distance`` from the EE when it appears. Its log line is
    :func:`~legws_daemon.formats.log_lines.reach_text`, which ``legws operator trace``
    reads back."""

    kind: ClassVar[EventKind] = "reach"
    reach: int
    of: int
    target: tuple[float, float, float]
    distance: float

    def detail(self) -> dict[str, Any]:
        d = Event.detail(self)
        d["target"] = [round(float(v), 4) for v in self.target]
        d["distance"] = round(self.distance, 4)
        return d

    def text(self) -> str:
        return reach_text(self.reach, self.of, self.target)


@dataclass(frozen=True, slots=True)
class CalibrationReached(Event):
    """The EE arrived at the target of reach ``reach`` (within 2 cm): ``seconds`` of
    control time and ``ticks`` since it appeared. Its log line is
    :func:`~legws_daemon.formats.log_lines.reached_text`."""

    kind: ClassVar[EventKind] = "reached"
    reach: int
    of: int
    seconds: float
    ticks: int

    def detail(self) -> dict[str, Any]:
        d = Event.detail(self)
        d["seconds"] = round(self.seconds, 3)
        return d

    def text(self) -> str:
        return reached_text(self.reach)


# --- faults and operator commands ------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Fault(Event):
    kind: ClassVar[EventKind] = "fault"
    error: str


@dataclass(frozen=True, slots=True)
class Recovered(Event):
    """A reset after a fault finished: the robot answers again, the task restarts."""

    kind: ClassVar[EventKind] = "recovered"
    task: str


@dataclass(frozen=True, slots=True)
class Reset(Event):
    """A reset finished: home, the task restarts."""

    kind: ClassVar[EventKind] = "reset"
    task: str


@dataclass(frozen=True, slots=True)
class Stop(Event):
    """The robot stopped: ``by`` is the authenticated role that stopped it (operator,
    observer, safety, bridge — from the key it came on — or ``daemon``), ``source`` and
    ``reason`` what the sender said (unauthenticated detail)."""

    kind: ClassVar[EventKind] = "stop"
    mode: str
    by: str = "operator"
    source: str | None = None
    reason: str | None = None
    #: stops of the same role carried out since its last stop event, not announced (a
    #: flood: at most one event a second per role)
    repeats: int = 0

    def text(self) -> str:
        said = f" ({self.source})" if self.source else ""
        why = f": {self.reason}" if self.reason else ""
        return f"stop by {self.by}{said}{why}"


# --- the operator's input ----------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class OperatorChanged(Event):
    """The operator lease changed hands: ``operator`` steers now (``None``: nobody; the next
    session that steers takes it), ``previous`` held it. Each is ``{"source", "session"}``."""

    kind: ClassVar[EventKind] = "operator"
    operator: dict[str, str | None] | None
    previous: dict[str, str | None] | None
    #: first_input | resumed | goodbye | timeout | stall | release | take_control
    reason: str

    def text(self) -> str:
        who = _who(self.operator) if self.operator else "nobody"
        return f"operator {who} ({self.reason}; was {_who(self.previous)})"


@dataclass(frozen=True, slots=True)
class Deadman(Event):
    """The dead-man state changed: ``on`` — no input reaches the robot (zero velocity,
    assistance paused) because of ``reason``; off — the operator's input moves it again."""

    kind: ClassVar[EventKind] = "deadman"
    on: bool
    reason: str | None  # no_operator | no_input | enable_released (None when off)


@dataclass(frozen=True, slots=True)
class InputRejected(Event):
    """Joystick messages were rejected for ``reason`` (invalid | auth | stale_seq |
    not_operator):
    ``count`` since the last such event (at most one per reason every few seconds),
    ``total`` so far; the last one's sender and error."""

    kind: ClassVar[EventKind] = "input_rejected"
    reason: str
    count: int
    total: int
    source: str | None
    session: str | None
    error: str | None


@dataclass(frozen=True, slots=True)
class Stall(Event):
    """The daemon itself stood still for ``seconds`` between two ticks (the process was
    paused: SIGSTOP, a swap storm, a debugger), longer than ``threshold``: it stopped the
    robot, dropped the input heard before (stale now) and the operator lease as after a
    timeout, and measures the robot side's heartbeat from its resume (its own pause is not
    the bridge's silence). ``stalls``: how many so far."""

    kind: ClassVar[EventKind] = "stall"
    seconds: float
    threshold: float
    stalls: int

    def text(self) -> str:
        return (
            f"stall seconds={self.seconds:.3f}: the daemon stood still (paused?) longer than "
            f"{self.threshold:g} s; robot stopped, input and lease dropped (stalls={self.stalls})"
        )


def _who(key: dict[str, str | None] | None) -> str:
    if key is None:
        return "nobody"
    session = key.get("session")
    return f"{key.get('source')}" + (f" [{session}]" if session else "")


# --- warnings --------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class AssistFailed(Event):
    """A step of the assisted action failed (timed out, made no progress, or could not be
    planned); control goes back to the user."""

    kind: ClassVar[EventKind] = "warning"
    assist: str
    phase: str
    error: str


@dataclass(frozen=True, slots=True)
class SetDown(Event):
    """A reset could not put the held object back: it sets it down instead."""

    kind: ClassVar[EventKind] = "warning"
    object: str
    phase: str
    reason: str

    def detail(self) -> dict[str, Any]:
        return {"reset": "set_down", **Event.detail(self)}


@dataclass(frozen=True, slots=True)
class Overrun(Event):
    kind: ClassVar[EventKind] = "warning"
    overrun_ms: float
    period_ms: float
    overruns: int


@dataclass(frozen=True, slots=True)
class TelemetryProblem(Event):
    kind: ClassVar[EventKind] = "warning"
    telemetry: str | None
    new_errors: int
    errors: int
    dropped: int
    control: str = "continues"


@dataclass(frozen=True, slots=True)
class InsecureTransport(Event):
    """A daemon that drives a real arm runs on a transport without authentication
    (``--insecure-transport``): anyone who reaches the port can steer it."""

    kind: ClassVar[EventKind] = "warning"
    insecure_transport: str

    def text(self) -> str:
        return (
            f"INSECURE TRANSPORT: {self.insecure_transport}; any process that reaches the "
            "port can steer the robot, command its bridge and fake its state (bench test only)"
        )


@dataclass(frozen=True, slots=True)
class RealtimeRefused(Event):
    """The profile asks for real-time scheduling of the loop and the system refused it:
    the loop runs at normal priority (longer ticks when the CPU is busy)."""

    kind: ClassVar[EventKind] = "warning"
    realtime: str
    control: str = "continues at normal priority"


@dataclass(frozen=True, slots=True)
class TraceFailed(Event):
    kind: ClassVar[EventKind] = "warning"
    trace: str
    control: str = "continues"


@dataclass(frozen=True, slots=True)
class NoPlan(Event):
    """A ``load_taskgraph`` without ``plan`` found no usable cached plan of the graph: its
    decisions run on the shipped layout (``reason`` says how to make one)."""

    kind: ClassVar[EventKind] = "warning"
    no_plan: str  # the task graph
    reason: str

    def text(self) -> str:
        return f"task graph {self.no_plan} runs on the shipped layout: {self.reason}"


@dataclass(frozen=True, slots=True)
class ConfirmsNeeded(Event):
    """At start: a decision whose goals are not all commit-certified from home in the layout
    it runs in (``layout``: ``plan`` or ``layout``; :mod:`.confirms`) — steered at straight,
    the posterior may stay below the threshold for ``goals``: a confirm commits them."""

    kind: ClassVar[EventKind] = "warning"
    confirms: str  # the decision
    layout: str
    goals: tuple[str, ...]  # those not commit-certified
    of: int  # the decision's goals
    commit_certificate: float  # K

    def detail(self) -> dict[str, Any]:
        d = Event.detail(self)
        d["commit_certificate"] = round(self.commit_certificate, 4)
        return d

    def text(self) -> str:
        where = "the plan's layout" if self.layout == "plan" else "the layout without a plan"
        return (
            f"confirms needed: decision {self.confirms} ({where}): {len(self.goals)} of "
            f"{self.of} goals not "
            f"commit-certified (K {self.commit_certificate:.3g}): {', '.join(self.goals)} — "
            "steered at straight, the posterior may stay below the threshold: confirm "
            "commits them"
        )


@dataclass(frozen=True, slots=True)
class PlaceObjects(Event):
    """A plan's layout on a robot that cannot move objects itself: where to put them."""

    kind: ClassVar[EventKind] = "warning"
    place: dict[str, dict[str, float]]
    stage: str
    certificate: float | None


@dataclass(frozen=True, slots=True)
class PlanDropped(Event):
    """A task graph was loaded without a plan while one was in use: its decisions now run on
    the shipped layout (``certificate``) instead of the planned one
    (``planned_certificate``, the plan's for the same decision when it has it)."""

    kind: ClassVar[EventKind] = "warning"
    plan: str  # the task graph of the dropped plan
    stage: str
    certificate: float | None
    planned_certificate: float | None


@dataclass(frozen=True, slots=True)
class Misplaced(Event):
    """Reported object poses leave the decision's placed layout off the plan (an object off
    its planned pose, whatever J says) or uncertified: every object off its outline with
    the correction in words, the unseen ones, the object whose move back gains the most
    (``move``, ``to``: its planned pose), and whether the placed layout is ``certified``
    all the same. The log line's verdict follows J's sign (:func:`.placing.verdict`)."""

    kind: ClassVar[EventKind] = "warning"
    certificate: float
    planned_certificate: float | None
    commit_certificate: float | None
    move: str | None
    to: dict[str, float] | None
    corrections: tuple[str, ...]  # "cup: 4 cm left, turn 20° anticlockwise"
    unseen: tuple[str, ...]
    stage: str
    certified: bool

    def detail(self) -> dict[str, Any]:
        d = Event.detail(self)
        for key in ("certificate", "planned_certificate", "commit_certificate"):
            if d[key] is not None:
                d[key] = round(d[key], 4)
        return d

    def text(self) -> str:
        what = list(self.corrections) + [f"{n}: unseen" for n in self.unseen]
        planned = (
            ""
            if self.planned_certificate is None
            else (f", planned {self.planned_certificate:+.2f}")
        )
        words = verdict(self.certificate, self.certified, bool(self.corrections))
        return (
            f"warning placement of {self.stage} {words} (J {self.certificate:+.2f}"
            f"{planned}): {'; '.join(what)}"
        )


@dataclass(frozen=True, slots=True)
class OperatorOutside(Event):
    """The live watch (``legws daemon --operator``): the operator model re-fitted over the
    last ``picks`` completed picks (``estimate``) is outside the operator file's intervals
    on the unsafe side of each number in ``outside`` (name -> ``{"seen", "certified"}``):
    the certificates shown are no longer this person's."""

    kind: ClassVar[EventKind] = "warning"
    operator_watch: str  # "operator alice: rho 0.93 seen, certified for ≤ 0.86"
    operator: str
    outside: dict[str, dict[str, float | str]]
    estimate: dict[str, float | str]
    picks: int

    def text(self) -> str:
        return f"warning {self.operator_watch}"


@dataclass(frozen=True, slots=True)
class OperatorInside(Event):
    """The live watch's estimate is back within the operator file's intervals after an
    :class:`OperatorOutside` warning."""

    kind: ClassVar[EventKind] = "operator_inside"
    operator_watch: str
    operator: str
    estimate: dict[str, float | str]
    picks: int

    def text(self) -> str:
        return self.operator_watch


@dataclass(frozen=True, slots=True)
class Placed(Event):
    """The placed layout of the decision is certified again (after a :class:`Misplaced`)."""

    kind: ClassVar[EventKind] = "placed"
    stage: str
    certificate: float
    commit_certificate: float | None

    def detail(self) -> dict[str, Any]:
        d = Event.detail(self)
        d["certificate"] = round(self.certificate, 4)
        if self.commit_certificate is not None:
            d["commit_certificate"] = round(self.commit_certificate, 4)
        return d
