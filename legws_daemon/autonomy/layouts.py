"""Where the objects stand: the planned layout, what a tracker reported, and what inference
uses.

The planned layout starts as the layout the daemon was given; a stage-specific plan
(``legws plan``) moves each decision's optimised objects to their planned poses when the
decision begins (:meth:`LayoutBook.plan_moves`). Poses reported on
``legws/<robot>/objects`` override the plan (:meth:`LayoutBook.observe`). When reported
poses make a decision's certificate non-positive while the plan's was positive,
:meth:`LayoutBook.misplaced` names the object whose move back gains the most, once per
decision and object.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping, Sequence

from legws_daemon.autonomy.events import Misplaced
from legws_daemon.errors import InputError
from legws_daemon.scene.scene import Layout, ObjectPose
from legws_daemon.task.plan import Plan, PlannedDecision


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
        self._misplaced: tuple[int, str] | None = None
        self.reset(layout, plan)

    def reset(self, layout: Layout, plan: Plan | None = None) -> None:
        """Start again from ``layout`` (nothing observed)."""
        self.plan = plan
        self.planned = dict(layout)
        self.observed = {}
        self._misplaced = None

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

    def observe(self, poses: Mapping[str, ObjectPose], movable: Collection[str]) -> bool:
        """Take reported poses of ``movable`` objects; ``True`` when any was known."""
        known = {n: p for n, p in poses.items() if n in movable}
        self.observed.update(known)
        return bool(known)

    def misplaced(
        self,
        decision: int,
        stage: str,
        names: Sequence[str],
        current: float,
        planned: float | None,
        certificate: Callable[[Layout], float],
    ) -> Misplaced | None:
        """The warning to send, or ``None``.

        Args:
            decision: the decision's number in the run (one warning per decision and object).
            stage: its label; names: its candidates.
            current: its certificate in :attr:`layout`; planned: in the plan.
            certificate: the decision's certificate of a layout.
        """
        if current > 0 or planned is None or planned <= 0:
            self._misplaced = None
            return None
        layout = self.layout
        best, best_gain = None, 0.0
        for n in names:
            if n in self.observed and n in self.planned:
                gain = certificate({**layout, n: self.planned[n]}) - current
                if gain > best_gain:
                    best, best_gain = n, gain
        if best is None or (decision, best) == self._misplaced:
            return None
        self._misplaced = (decision, best)
        to = self.planned[best]
        return Misplaced(current, planned, best, {"x": to.x, "y": to.y, "yaw": to.yaw}, stage)
