"""The live watch of ``legws daemon --operator``: is the person at the joystick still the
person the operator file describes?

**Segments** (:class:`PickSegments`), as ``legws operator trace`` takes them from a
recording (:mod:`legws_daemon.telemetry.operator_trace`): a pick whose goal is known is a
decision committed by inference or by the operator's confirm (not a single candidate) whose
stage then finished without a cancel; its segment is the decision's teleoperation ticks —
the EE position each tick read and the deflection the controller used, zero on a tick
without input — from the (re)start of inference to the commit, toward the committed goal.
A cancel, a failed assistance, a stop, a fault, a reset or a load drops the pick under way.

**The window**: the last :data:`WINDOW` completed picks. From :data:`MINIMUM` picks on,
each completed pick starts a re-fit of the operator model over the window
(:func:`~legws_daemon.core.operator_fit.fit_operator`, point estimates only: 1-3 s) on the
watch's own thread, never on the control loop; a pick that completes while a fit runs
makes one more fit, of the newest window, when it ends. :meth:`OperatorWatch.poll` (the
loop, every tick) takes a finished fit without waiting for one.

**The rule** (:func:`judge`): each number on its unsafe side of the file's 95 % interval —
speed below its low end, sigma and rho above their high end, ``|bias|`` beyond the end
farther from zero — by more than the window's own scatter, and another steering. The
scatter of a window's estimate, measured on the stand-in (``desk``, 10 picks a window, 4-12
windows an operator; docs/operator.md): standard deviation 0.003-0.005 of speed for an
operator at full deflection (0.024 for one at 0.8), 0.001 m/s of sigma, 0.009-0.013 of
rho, 1.5-3.5° of bias (5.2° at most from a true 0 in 12 windows). The tolerances at a full
window, :data:`TOLERANCE`: 0.05 of speed, 15 % of sigma, 0.05 of rho (about 4 standard
deviations) and 8° of bias (2.5); with fewer picks they grow as ``sqrt(WINDOW / picks)``
(the scatter of an estimate from fewer ticks). A change like rho 0.5 -> 0.9 or a 20° bias
is told within half a window; one of the size of the window's noise is not.

A judgement with something outside is a ``warning`` (:class:`~.events.OperatorOutside`:
``operator alice: rho 0.93 seen, certified for ≤ 0.86``), again when what is outside
changes (another number, or back inside and out again); back inside after a warning, an
``operator_inside`` note.
"""

from __future__ import annotations

import contextlib
import math
from collections import deque
from concurrent.futures import Executor, Future
from dataclasses import dataclass
from typing import Any

import numpy as np

from legws_daemon.autonomy.events import (
    AssistFailed,
    Cancel,
    Commit,
    Event,
    Fault,
    Loaded,
    OperatorInside,
    OperatorOutside,
    Recovered,
    Reset,
    StageDone,
    Stop,
    TaskDone,
)
from legws_daemon.autonomy.inputs import TickRecord
from legws_daemon.autonomy.modes import Mode
from legws_daemon.core.geometry import FloatArray
from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.operator_fit import Fit, fit_operator
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.formats.operator_file import OperatorFile

#: Completed picks the operator is re-fitted over.
WINDOW = 10
#: Completed picks before the first judgement.
MINIMUM = 5
#: How far beyond the file's interval a full window's estimate must be to count as outside
#: (module docstring): speed and rho in their units, sigma relative to the interval's high
#: end, bias in degrees.
TOLERANCE = {"speed": 0.05, "sigma": 0.15, "rho": 0.05, "bias_deg": 8.0}
#: Longest decision kept as one segment, ticks (ten minutes at 20 Hz): older ticks go.
MAX_SEGMENT_TICKS = 12_000

#: A segment: EE positions and deflections ``(n, 3)``, the goal's position ``(3,)``.
Segment = tuple[FloatArray, FloatArray, FloatArray]


@dataclass(frozen=True, slots=True)
class Outside:
    """One number of the window's estimate outside the file's model, on its unsafe side.

    Attributes:
        name: ``speed``, ``sigma``, ``rho``, ``bias_deg`` or ``steering``.
        seen: the window's estimate.
        certified: the end of the file's interval the certificates use (``certify_with``):
            the least speed, the most sigma, rho and ``|bias|``; the file's steering.
    """

    name: str
    seen: float | str
    certified: float | str

    @property
    def text(self) -> str:
        seen, cert = self.seen, self.certified
        if isinstance(seen, str) or isinstance(cert, str):
            return f"{self.name} {seen} seen, certified for {cert}"
        if self.name == "speed":
            return f"speed {seen:.2f} seen, certified for ≥ {cert:.2f}"
        if self.name == "sigma":
            return f"sigma {seen:.3f} m/s seen, certified for ≤ {cert:.3f} m/s"
        if self.name == "bias_deg":
            return f"bias {seen:+.1f}° seen, certified for |bias| ≤ {cert:.1f}°"
        return f"{self.name} {seen:.2f} seen, certified for ≤ {cert:.2f}"

    def detail(self) -> dict[str, float | str]:
        seen = self.seen if isinstance(self.seen, str) else round(self.seen, 4)
        cert = self.certified if isinstance(self.certified, str) else round(self.certified, 4)
        return {"seen": seen, "certified": cert}


def judge(
    estimate: OperatorModel, file: OperatorFile, picks: int, window: int = WINDOW
) -> tuple[Outside, ...]:
    """What of ``estimate`` (fitted over ``picks`` picks) is outside ``file``'s intervals
    on its unsafe side by more than :data:`TOLERANCE` grown by ``sqrt(window / picks)``."""
    grow = math.sqrt(window / max(picks, 1))
    iv = file.intervals
    out = []
    low = iv["speed"][0]
    if estimate.speed < low - TOLERANCE["speed"] * grow:
        out.append(Outside("speed", estimate.speed, low))
    high = iv["sigma"][1]
    if estimate.sigma > high * (1.0 + TOLERANCE["sigma"] * grow):
        out.append(Outside("sigma", estimate.sigma, high))
    high = iv["rho"][1]
    if estimate.rho > high + TOLERANCE["rho"] * grow:
        out.append(Outside("rho", estimate.rho, high))
    far = max(abs(iv["bias_deg"][0]), abs(iv["bias_deg"][1]))
    if abs(estimate.bias_deg) > far + TOLERANCE["bias_deg"] * grow:
        out.append(Outside("bias_deg", estimate.bias_deg, far))
    if estimate.steering != file.certify_with.steering:
        out.append(Outside("steering", estimate.steering, file.certify_with.steering))
    return tuple(out)


class PickSegments:
    """The segments of completed picks, from the controller's events and tick records (in
    the order the controller makes them: a tick's events, then its record)."""

    def __init__(self) -> None:
        self._ee: deque[FloatArray] = deque(maxlen=MAX_SEGMENT_TICKS)
        self._u: deque[FloatArray] = deque(maxlen=MAX_SEGMENT_TICKS)
        self._pending: tuple[str, Segment] | None = None  # committed, waiting for its end
        self._skip = False  # the record of the tick whose events restarted inference

    def _restart(self) -> None:
        self._ee.clear()
        self._u.clear()
        self._skip = True

    def event(self, event: Event, goal_position: FloatArray | None = None) -> Segment | None:
        """Take one event (``goal_position``: the committed goal's, for a :class:`Commit`);
        the segment of a pick it completes, else ``None``."""
        match event:
            case Commit() if not event.single and goal_position is not None:
                ee = np.array(self._ee, dtype=np.float64).reshape(-1, 3)
                u = np.array(self._u, dtype=np.float64).reshape(-1, 3)
                goal = np.asarray(goal_position, dtype=np.float64).copy()
                self._pending = (event.goal, (ee, u, goal))
                self._restart()
            case Commit():
                self._pending = None
                self._restart()
            case StageDone():
                pending, self._pending = self._pending, None
                self._restart()
                if pending is not None and pending[0] == event.goal and not event.cancelled:
                    return pending[1]
            case Cancel() | AssistFailed() | Stop() | Fault() | Reset() | Recovered() | Loaded():
                self._pending = None
                self._restart()
            case TaskDone():
                self._restart()
            case _:
                pass
        return None

    def tick(self, rec: TickRecord) -> None:
        """Take one tick's record: a teleoperation tick adds to the decision's segment."""
        if self._skip:
            self._skip = False
            return
        if rec.mode != Mode.TELEOP or rec.state is None:
            return
        self._ee.append(np.array(rec.state.ee_position, dtype=np.float64))
        u = np.zeros(3) if rec.joystick is None else np.array(rec.joystick, dtype=np.float64)
        self._u.append(u)


@dataclass(frozen=True, slots=True)
class Estimate:
    """A window's fit: the model and how many picks and ticks it saw."""

    model: OperatorModel
    picks: int
    ticks: int

    def status(self) -> dict[str, Any]:
        m = self.model
        return {
            "speed": round(m.speed, 4),
            "sigma": round(m.sigma, 5),
            "rho": round(m.rho, 4),
            "bias_deg": round(m.bias_deg, 2),
            "steering": m.steering,
            "picks": self.picks,
            "ticks": self.ticks,
        }


class OperatorWatch:
    """The live watch over one operator file (see the module docstring).

    Args:
        file: the operator file the daemon certifies for.
        params: the daemon's parameters (``v_max``, ``dt``: the fit's units).
        window: completed picks fitted over; minimum: picks before the first judgement.
        executor: where fits run (the daemon: a thread of its own); ``None``: at once, on
            the caller's thread (in-process simulations).
    """

    def __init__(
        self,
        file: OperatorFile,
        params: Params,
        *,
        window: int = WINDOW,
        minimum: int = MINIMUM,
        executor: Executor | None = None,
    ) -> None:
        if not 2 <= minimum <= window:
            raise InputError(f"expected 2 <= minimum <= window, got {minimum}, {window}")
        self.file = file
        self.params = params
        self.window = window
        self.minimum = minimum
        self.executor = executor
        self.segments = PickSegments()
        self.recent: deque[Segment] = deque(maxlen=window)
        self.picks = 0  # completed picks seen
        self.estimate: Estimate | None = None
        self.outside: tuple[Outside, ...] = ()
        self.error: str | None = None
        self.fits = 0
        self._future: Future[Fit] | None = None
        self._fitting: tuple[int, int] | None = None  # (picks, ticks) of the running fit
        self._again = False
        self._warned: tuple[str, ...] | None = None  # names outside at the last warning
        self._events: list[Event] = []

    # --- input ------------------------------------------------------------------------
    def event(self, event: Event, goal_position: FloatArray | None = None) -> None:
        """One controller event (``goal_position``: the committed goal's, for a commit)."""
        segment = self.segments.event(event, goal_position)
        if segment is None:
            return
        self.picks += 1
        self.recent.append(segment)
        if len(self.recent) >= self.minimum:
            self._fit()

    def tick(self, rec: TickRecord) -> None:
        """One tick's record (after its events)."""
        self.segments.tick(rec)

    # --- fitting ----------------------------------------------------------------------
    def _fit(self) -> None:
        if self._future is not None:
            self._again = True
            return
        window = list(self.recent)
        ticks = sum(len(s[0]) for s in window)
        self._fitting = (len(window), ticks)
        params = self.params

        def work() -> Fit:
            return fit_operator(window, params, resamples=0)

        if self.executor is None:
            future: Future[Fit] = Future()
            try:
                future.set_result(work())
            except Exception as err:  # kept for poll, as a thread's future keeps it
                future.set_exception(err)
            self._future = future
            self._take()
        else:
            self._future = self.executor.submit(work)

    def poll(self) -> list[Event]:
        """The events of the fits that finished since the last call (never waits)."""
        self._take()
        out, self._events = self._events, []
        return out

    def _take(self) -> None:
        future = self._future
        if future is None or not future.done():
            return
        self._future = None
        picks, ticks = self._fitting or (0, 0)
        try:
            fit = future.result()
        except InputError as err:
            self.error = str(err)
        except Exception as err:  # a bug in the fit must not reach the control loop
            self.error = f"{type(err).__name__}: {err}"
        else:
            self.fits += 1
            self.error = None
            self.estimate = Estimate(fit.model, picks, ticks)
            self._judged(judge(fit.model, self.file, picks, self.window))
        if self._again:
            self._again = False
            self._fit()

    def _judged(self, outside: tuple[Outside, ...]) -> None:
        self.outside = outside
        est = self.estimate
        assert est is not None
        names = tuple(o.name for o in outside)
        name = self.file.name
        if outside:
            if names != self._warned:
                self._warned = names
                self._events.append(
                    OperatorOutside(
                        self.warning or "", name, {o.name: o.detail() for o in outside},
                        est.status(), est.picks,
                    )
                )  # fmt: skip
        elif self._warned is not None:
            self._warned = None
            text = (
                f"operator {name}: back within the certified model over the last {est.picks} picks"
            )
            self._events.append(OperatorInside(text, name, est.status(), est.picks))

    # --- what it says -------------------------------------------------------------------
    @property
    def warning(self) -> str | None:
        """``operator alice: rho 0.93 seen, certified for ≤ 0.86`` while something is
        outside, else ``None``."""
        if not self.outside:
            return None
        return f"operator {self.file.name}: " + "; ".join(o.text for o in self.outside)

    def status(self) -> dict[str, Any]:
        """Status ``operator_model.watch``."""
        return {
            "window": self.window,
            "minimum": self.minimum,
            "picks": self.picks,
            "estimate": None if self.estimate is None else self.estimate.status(),
            "outside": [o.name for o in self.outside],
            "warning": self.warning,
            "error": self.error,
        }

    def lines(self) -> tuple[str, ...]:
        """The watch in a line for the Rerun status panel."""
        if self.warning is not None:
            return (f"watch: {self.warning}",)
        if self.estimate is None:
            need = max(self.minimum - len(self.recent), 0)
            return (f"watch: {self.picks} picks completed, judged from {self.minimum} ({need} "
                    "more)",)  # fmt: skip
        est = self.estimate
        return (f"watch: within the certified model over the last {est.picks} picks "
                f"({est.model.describe()})",)  # fmt: skip

    def wait(self, timeout: float | None = None) -> None:
        """Wait for the running fit (tests, shutdown)."""
        future = self._future
        if future is not None:
            with contextlib.suppress(Exception):  # _take records it
                future.result(timeout=timeout)
            self._take()
