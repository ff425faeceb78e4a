"""A calibration (``legws operator calibrate``, method.md §10): the person steers the EE to
one target at a time, the controller in mode ``calibrate`` — teleoperation without an
observer, a commit or assistance — and records each reach.

The targets (:func:`targets_for`) are drawn in free space above the scene's table
(:class:`~legws_daemon.core.calibration.CalibrationBox`: the scene's x and y bounds, above
its tallest object, up to 10 cm over the EE home, and inside the profile's workspace box),
the first from where the EE is. A reach appears on a tick (:class:`CalibrationReach`,
logged as ``calibration reach=i of=n target=x,y,z``), and every tick of it in mode
``calibrate`` records the EE position (the state the tick read) and the deflection the
controller used (zero on a tick without input). It is done on the tick the EE is within
:data:`~legws_daemon.core.calibration.ARRIVED` of the target (:class:`CalibrationReached`,
``calibration reach=i done``; that tick sends zero and belongs to no reach); the next
target appears on the next tick, and after the last the controller goes ``idle``. The
recording holds the same segments (:mod:`legws_daemon.telemetry.operator_trace`: the ticks
in mode ``calibrate`` from a reach's line to its ``done`` line).

A stop or a fault interrupts the reach under way: its ticks are dropped, and after the
operator's ``reset`` (the arm goes home) the same target appears again.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from legws_daemon.autonomy.events import CalibrationReach, CalibrationReached
from legws_daemon.core.calibration import ARRIVED, CalibrationBox, calibration_targets
from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError
from legws_daemon.safety.envelope import Box
from legws_daemon.scene.grasps import extents
from legws_daemon.scene.scene import Scene

#: Status ``stage`` and the name of the one target in status ``targets`` while calibrating.
CALIBRATION = "calibration"


def calibration_box(scene: Scene, workspace: Box) -> CalibrationBox:
    """The box targets are drawn in: above the scene's table within its x and y bounds,
    clear of its tallest object, up to 10 cm above the EE home; cut to the profile's
    workspace box (5 cm inside it).

    Raises:
        InputError: the two leave no room.
    """
    ws = scene.workspace
    highest = max((extents(o.shape, tuple(o.size))[2] for o in scene.objects.values()), default=0.0)
    box = CalibrationBox.above_table(
        ws.x_range, ws.y_range, ws.table_height, highest, float(scene.home.position[2])
    )
    low = np.maximum(box.low, workspace.lower + 0.05)
    high = np.minimum(box.high, workspace.upper - 0.05)
    if np.any(low >= high):
        span = f"{box.low.round(3).tolist()}..{box.high.round(3).tolist()}"
        raise InputError(
            f"the scene's calibration box {span} lies outside the profile's workspace box",
            field="workspace",
        )
    return CalibrationBox(low, high)


def targets_for(
    scene: Scene, workspace: Box, start: FloatArray, count: int, seed: int
) -> list[FloatArray]:
    """``count`` calibration targets of ``scene`` (:func:`calibration_box`), the first from
    ``start``, rounded to 0.1 mm (as the log line writes them, so that the recording and
    the trace agree); the same seed, the same targets.

    Raises:
        InputError: ``count`` outside 2..200, or no room for reaches.
    """
    box = calibration_box(scene, workspace)
    targets = calibration_targets(count, box, start, np.random.default_rng(seed))
    return [np.round(t, 4) for t in targets]


@dataclass(frozen=True, slots=True)
class Reach:
    """One reach done: per tick the EE position and the deflection used ``(n, 3)``, the
    target ``(3,)``, and how long it took (control time, s)."""

    index: int
    ee: FloatArray
    u: FloatArray
    target: FloatArray
    seconds: float


@dataclass
class CalibrationRun:
    """The reaches of one calibration, one target at a time (see the module docstring).

    Args:
        targets: the targets, in order.
        dt: the control period, s.
    """

    targets: list[FloatArray]
    dt: float
    #: the reach under way (0-based); ``len(targets)`` when all are done
    index: int = 0
    #: the tick its target appeared (``None``: it appears on the next tick)
    shown: int | None = None
    done: list[Reach] = field(default_factory=list)
    _ee: list[FloatArray] = field(default_factory=list)
    _u: list[FloatArray] = field(default_factory=list)

    @property
    def count(self) -> int:
        return len(self.targets)

    @property
    def finished(self) -> bool:
        return self.index >= len(self.targets)

    @property
    def target(self) -> FloatArray | None:
        """The target shown now (``None``: none yet, or all reached)."""
        if self.finished or self.shown is None:
            return None
        return self.targets[self.index]

    def step(
        self, tick: int, position: FloatArray, u: FloatArray | None
    ) -> tuple[list[CalibrationReach | CalibrationReached], bool]:
        """One tick in mode ``calibrate`` with the EE at ``position`` and the deflection
        ``u`` (``None``: no input): the events it brings, and whether the tick drives
        (``False``: the target was just reached, the tick sends zero)."""
        events: list[CalibrationReach | CalibrationReached] = []
        if self.finished:
            return events, False
        target = self.targets[self.index]
        here = np.asarray(position, dtype=np.float64)
        if self.shown is None:
            self.shown = tick
            self._ee, self._u = [], []
            xyz = (float(target[0]), float(target[1]), float(target[2]))
            distance = float(np.linalg.norm(target - here))
            events.append(CalibrationReach(self.index + 1, self.count, xyz, distance))
        if float(np.linalg.norm(target - here)) < ARRIVED:
            ticks = tick - self.shown
            seconds = ticks * self.dt
            ee = np.array(self._ee, dtype=np.float64).reshape(-1, 3)
            us = np.array(self._u, dtype=np.float64).reshape(-1, 3)
            self.done.append(Reach(self.index + 1, ee, us, target.copy(), seconds))
            events.append(CalibrationReached(self.index + 1, self.count, seconds, ticks))
            self.index += 1
            self.shown = None
            return events, False
        self._ee.append(here.copy())
        self._u.append(np.zeros(3) if u is None else np.asarray(u, dtype=np.float64).copy())
        return events, True

    def interrupt(self) -> None:
        """A stop or fault: the reach under way is dropped; its target appears again."""
        self.shown = None
        self._ee, self._u = [], []

    def status(self, position: FloatArray | None) -> dict[str, object] | None:
        """Status ``calibration``: ``{"reach", "of", "target", "distance"}`` of the target
        shown, ``None`` when none is (between reaches, or all done)."""
        target = self.target
        if target is None:
            return None
        distance = None if position is None else float(np.linalg.norm(target - position))
        return {
            "reach": self.index + 1,
            "of": self.count,
            "target": [round(float(v), 4) for v in target],
            "distance": None if distance is None else round(distance, 4),
        }
