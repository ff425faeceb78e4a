"""Where the objects stand: the planned layout, what a tracker reported, and what inference
uses.

The planned layout starts as the layout the daemon was given; a stage-specific plan
(``legws plan``) moves each decision's optimised objects to their planned poses when the
decision begins (:meth:`LayoutBook.plan_moves`). Poses reported on
``legws/<robot>/objects`` override the plan for movable objects (:meth:`LayoutBook.observe`);
every reported object, fixed ones too, is judged against where it should stand
(:meth:`LayoutBook.placements`, :mod:`.placing`). While an object is off its planned pose
(whatever J says) or the placed layout of a decision is not certified,
:meth:`LayoutBook.guide` says what to move: again when what is wrong changes, and as a
reminder every :data:`REMIND_EVERY` seconds.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping

from legws_daemon.autonomy.events import Event, Misplaced, Placed
from legws_daemon.autonomy.placing import STALE_AFTER, ObjectPlacement, PlacementReport, judge
from legws_daemon.errors import InputError
from legws_daemon.scene.scene import Layout, ObjectPose
from legws_daemon.task.plan import Plan, PlannedDecision

#: While a placed layout stays uncertified and nothing changes, the warning again after
#: this long (s).
REMIND_EVERY = 10.0


class LayoutBook:
    """The layouts of one run (see the module docstring).

    Args:
        layout: the planned layout of the scene's movable objects.
        plan: stage-specific layouts of the task graph, or ``None``.
    """

    def __init__(self, layout: Layout, plan: Plan | None = None) -> None:
        self.plan: Plan | None = None
        self.planned: Layout = {}
        self.observed: Layout = {}
        #: every object a tracker reported (fixed ones too): its last pose and when (the
        #: loop's monotonic clock)
        self.seen: dict[str, tuple[ObjectPose, float]] = {}
        #: objects the newest report says the tracker does not see
        self.unseen: set[str] = set()
        self._warned: tuple[int, bool, tuple[str, ...], tuple[str, ...]] | None = None
        self._warned_at = 0.0
        self.reset(layout, plan)

    def reset(self, layout: Layout, plan: Plan | None = None) -> None:
        """Start again from ``layout`` (nothing observed)."""
        self.plan = plan
        self.planned = dict(layout)
        self.observed = {}
        self.seen = {}
        self.unseen = set()
        self._warned = None

    @property
    def layout(self) -> Layout:
        """What inference uses: the planned poses, overridden by the observed ones."""
        return {**self.planned, **self.observed}

    def plan_moves(self, label: str) -> tuple[Layout, PlannedDecision] | None:
        """The objects the plan moves for the decision ``label`` (now planned there), and
        the decision; ``None`` when there is no plan, it does not know the decision, or
        nothing moves."""
        if self.plan is None:
            return None
        try:
            decision = self.plan.decision(label)
        except InputError:
            return None  # the plan does not know this decision: keep the layout
        planned = self.plan.layout_for(decision.label)
        moves = {n: planned[n] for n in decision.optimised if n in planned}
        if not moves or all(self.planned.get(n) == p for n, p in moves.items()):
            return None
        self.planned.update(moves)
        return moves, decision

    def observe(
        self,
        poses: Mapping[str, ObjectPose],
        unseen: Collection[str],
        known: Collection[str],
        movable: Collection[str],
        now: float,
    ) -> bool:
        """Take a tracker's report: measured ``poses`` and the ``unseen`` objects, of the
        scene's ``known`` objects (others are ignored); the ``movable`` ones' poses become
        what inference uses. An unseen object keeps its pose. ``True`` when any was known."""
        measured = {n: p for n, p in poses.items() if n in known}
        missing = {n for n in unseen if n in known and n not in measured}
        for n, p in measured.items():
            self.seen[n] = (p, now)
        self.unseen = (self.unseen - set(measured)) | missing
        self.observed.update({n: p for n, p in measured.items() if n in movable})
        return bool(measured or missing)

    @property
    def tracking(self) -> bool:
        """A tracker has reported on some object."""
        return bool(self.seen or self.unseen)

    def placements(
        self, now: float, should: Mapping[str, ObjectPose], symmetry: Mapping[str, int]
    ) -> tuple[ObjectPlacement, ...]:
        """Every tracked object of ``should`` (where each object should stand, in scene
        order) judged: unseen when the tracker says so or has not seen it for
        :data:`~.placing.STALE_AFTER` seconds."""
        out = []
        for name, planned in should.items():
            last = self.seen.get(name)
            if last is None and name not in self.unseen:
                continue  # not tracked
            age = None if last is None else now - last[1]
            stale = age is None or age > STALE_AFTER or name in self.unseen
            measured = None if stale or last is None else last[0]
            out.append(judge(name, planned, measured, symmetry.get(name, 1), age))
        return tuple(out)

    def guide(
        self,
        report: PlacementReport,
        decision: int,
        now: float,
        certificate: Callable[[Layout], float],
    ) -> Event | None:
        """The event to send about ``report`` (decision ``decision``), or ``None``: a
        :class:`Misplaced` warning while an object is misplaced — whatever J says — or the
        layout is not certified and something is off (again when that or the verdict
        changes, or after :data:`REMIND_EVERY` s); a :class:`Placed` when, after a warning,
        it is certified with nothing misplaced."""
        if report.certified is None or report.certificate is None:
            return None
        wrong = tuple(o.name for o in report.misplaced)
        if report.certified and not wrong:
            if self._warned is None or self._warned[0] != decision:
                return None
            self._warned = None
            return Placed(report.stage, report.certificate, report.commit_certificate)
        if not wrong and not report.unseen:
            return None  # all in place, and not certified all the same: nothing to move
        key = (decision, report.certified, wrong, report.unseen)
        if key == self._warned and now - self._warned_at < REMIND_EVERY:
            return None
        self._warned, self._warned_at = key, now
        best = self._best_move(report.certificate, certificate)
        to = None if best is None else self.planned[best]
        return Misplaced(
            report.certificate, report.planned_certificate, report.commit_certificate, best,
            None if to is None else {"x": to.x, "y": to.y, "yaw": to.yaw},
            tuple(o.text for o in report.misplaced), report.unseen, report.stage,
            report.certified,
        )  # fmt: skip

    def _best_move(self, current: float, certificate: Callable[[Layout], float]) -> str | None:
        """The observed object whose move back to its planned pose gains the most."""
        layout = self.layout
        best, best_gain = None, 0.0
        for n in self.observed:
            if n in self.planned:
                try:
                    gain = certificate({**layout, n: self.planned[n]}) - current
                except InputError:
                    continue
                if gain > best_gain:
                    best, best_gain = n, gain
        return best
