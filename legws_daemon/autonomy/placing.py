"""Guidance while objects are placed by hand: which object is off its planned pose, by how
much, in words a person at the table follows, and whether the placed layout is certified.

A tracker (``legws track``) reports where objects really stand on ``legws/<robot>/objects``.
Each tracked object is ``placed`` (within :data:`POSITION_TOLERANCE` and
:data:`YAW_TOLERANCE` of its planned pose), ``misplaced`` (with the correction: the move
from where it stands to where it should) or ``unseen`` (the tracker says so, or has not
seen it for :data:`STALE_AFTER` seconds; its last pose stays as it was: an unseen object is
never moved). Directions are those of the placement mat: the robot at its bottom edge,
``left`` the robot's left (+y), ``away from the robot`` +x; turns seen from above.

An object off its planned pose is misplaced whatever J says: a placed layout may keep
J > 0 and still not be the plan. The verdict's words follow J's sign
(:func:`verdict`): ``NOT certified`` only for J <= 0; J > 0 with a candidate unseen is
``unconfirmed`` (J is that of the poses last seen); J > 0 with every candidate seen is
``certified``, ``off the plan`` while something is misplaced.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

from legws_daemon.scene.scene import ObjectPose

#: Farther than this from its planned centre, an object is misplaced (m): twice what the
#: tracker's 95th percentile error allows (5 mm), so noise alone does not flag it.
POSITION_TOLERANCE = 0.01
#: Turned farther than this from its planned yaw (modulo its symmetry), misplaced (rad).
YAW_TOLERANCE = math.radians(5.0)
#: An object the tracker has not reported for this long is unseen (s): ten frames at 10 Hz.
STALE_AFTER = 1.0

State = Literal["placed", "misplaced", "unseen"]


def wrap(angle: float, symmetry: int) -> float:
    """``angle`` in ``(-period/2, period/2]`` for a ``symmetry``-fold object (0: any turn
    looks the same, so no turn is ever needed)."""
    if symmetry == 0:
        return 0.0
    period = 2 * math.pi / symmetry
    a = math.fmod(angle, period)
    if a > period / 2:
        a -= period
    elif a <= -period / 2:
        a += period
    return a


def verdict(certificate: float, certified: bool, misplaced: bool) -> str:
    """The verdict on a placed layout in words that follow the sign of J (``certificate``):
    ``certified`` needs J > 0 and no candidate unseen (``certified``); ``misplaced``: some
    tracked object is off its planned pose."""
    if certificate <= 0:
        return "NOT certified"
    if not certified:
        return "unconfirmed, a candidate unseen"
    return "off the plan, certified all the same" if misplaced else "certified"


def _length(metres: float) -> str:
    cm = abs(metres) * 100
    return f"{cm:.0f} cm" if cm >= 1.95 else f"{cm:.1f} cm"


def correction_text(name: str, dx: float, dy: float, dyaw: float) -> str:
    """``cup: 4 cm left, 2 cm towards the robot, turn 20° anticlockwise`` — the move that
    puts the object on its outline; components within the tolerances are left out."""
    parts = []
    if abs(dy) >= POSITION_TOLERANCE / 2:
        parts.append(f"{_length(dy)} {'left' if dy > 0 else 'right'}")
    if abs(dx) >= POSITION_TOLERANCE / 2:
        parts.append(f"{_length(dx)} {'away from the robot' if dx > 0 else 'towards the robot'}")
    if abs(dyaw) > YAW_TOLERANCE:
        turn = "anticlockwise" if dyaw > 0 else "clockwise"
        parts.append(f"turn {math.degrees(abs(dyaw)):.0f}° {turn}")
    return f"{name}: {', '.join(parts) or 'in place'}"


@dataclass(frozen=True, slots=True)
class ObjectPlacement:
    """One tracked object: its state, and the correction when misplaced.

    Attributes:
        name: the object.
        state: placed, misplaced or unseen.
        move: the correction ``{"x", "y", "yaw"}`` (planned minus measured; m, rad), only
            when misplaced.
        age: seconds since the tracker last saw it (``None``: never seen).
    """

    name: str
    state: State
    move: dict[str, float] | None = None
    age: float | None = None

    @property
    def text(self) -> str:
        if self.state == "unseen":
            return (
                f"{self.name}: unseen"
                if self.age is None
                else (f"{self.name}: unseen for {self.age:.0f} s")
            )
        if self.move is None:
            return f"{self.name}: in place"
        return correction_text(self.name, self.move["x"], self.move["y"], self.move["yaw"])

    def status(self) -> dict[str, Any]:
        out: dict[str, Any] = {"state": self.state, "text": self.text}
        if self.move is not None:
            out["move"] = {k: round(v, 4) for k, v in self.move.items()}
        if self.age is not None:
            out["age"] = round(self.age, 2)
        return out


def judge(
    name: str, planned: ObjectPose, measured: ObjectPose | None, symmetry: int, age: float | None
) -> ObjectPlacement:
    """The placement of one object: ``measured`` is ``None`` when it is unseen."""
    if measured is None:
        return ObjectPlacement(name, "unseen", age=age)
    dx, dy = planned.x - measured.x, planned.y - measured.y
    dyaw = wrap(planned.yaw - measured.yaw, symmetry)
    if math.hypot(dx, dy) <= POSITION_TOLERANCE and abs(dyaw) <= YAW_TOLERANCE:
        return ObjectPlacement(name, "placed", age=age)
    return ObjectPlacement(name, "misplaced", {"x": dx, "y": dy, "yaw": dyaw}, age)


@dataclass(frozen=True, slots=True)
class PlacementReport:
    """The placed layout of the current decision, as a tracker sees it.

    Attributes:
        stage: the decision's label.
        objects: every tracked object, in scene order.
        certificate: ``J`` of the decision's candidates in the placed layout (``None``:
            a single candidate, nothing to infer).
        planned_certificate: ``J`` in the planned layout.
        commit_certificate: ``K`` (method.md §9) in the placed layout; commit_certified:
            how many candidates are commit-certified there.
        certified: ``J > 0`` and no candidate unseen (``None`` without inference); an
            object off its planned pose does not change it (it is :attr:`misplaced`, and
            warned about, whatever J says).
    """

    stage: str
    objects: tuple[ObjectPlacement, ...]
    certificate: float | None
    planned_certificate: float | None
    commit_certificate: float | None
    commit_certified: int | None
    certified: bool | None

    def of_state(self, state: State) -> tuple[ObjectPlacement, ...]:
        return tuple(o for o in self.objects if o.state == state)

    @property
    def misplaced(self) -> tuple[ObjectPlacement, ...]:
        return self.of_state("misplaced")

    @property
    def unseen(self) -> tuple[str, ...]:
        return tuple(o.name for o in self.of_state("unseen"))

    def lines(self) -> list[str]:
        """What an operator reads: the verdict, then one line per object not in place."""
        if self.certified is None or self.certificate is None:
            head = "placement: nothing to certify (one candidate)"
        else:
            words = verdict(self.certificate, self.certified, bool(self.misplaced))
            head = f"placement {words}: J {_number(self.certificate)}"
            if self.commit_certificate is not None:
                head += f", K {_number(self.commit_certificate)}"
        return [head] + [o.text for o in self.objects if o.state != "placed"]

    def status(self) -> dict[str, Any]:
        """The status message's ``placement``."""
        return {
            "stage": self.stage,
            "certified": self.certified,
            "certificate": _rounded(self.certificate),
            "planned_certificate": _rounded(self.planned_certificate),
            "commit_certificate": _rounded(self.commit_certificate),
            "commit_certified": self.commit_certified,
            "objects": {o.name: o.status() for o in self.objects},
            "misplaced": [o.name for o in self.misplaced],
        }


def _rounded(value: float | None) -> float | None:
    return None if value is None else round(value, 4)


def _number(value: float | None) -> str:
    return "-" if value is None else f"{value:+.2f}"
