"""What one control tick shows: the record handed to the recording once per tick.

The daemon's loop builds one :class:`TickSnapshot` per tick (on its own thread, from the
tick's record and the controller) and hands it to the telemetry worker, which passes it to
:meth:`~legws_daemon.telemetry.rerun_log.RerunLog.log_tick`. Every field is typed here, so
a field the recording draws and the loop forgets to fill (or fills with the wrong type) is
mypy's error, not a silent gap in the recording.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from legws_daemon.core.geometry import FloatArray


@dataclass(frozen=True, slots=True)
class TickSnapshot:
    """One tick as the recording draws it.

    ``posterior`` is ``None`` when nothing is being inferred (the objects are then labelled
    with their names only, and the plot has a gap). ``gripper_half_gap`` is half the
    fingers' opening (m, :func:`~legws_daemon.robot.visual.finger_half_gap`); ``phase``,
    ``operator``, ``fault`` (``None``: none) and ``stage`` (the task's current stage, also
    one without inference; default: the last set up) fill the status panel. ``placement``:
    the lines of a tracker's placement report (the verdict, then each object not in place),
    shown in the status panel; ``corrections``: the misplaced objects' moves, from where
    each stands to where it should (``world/placement``). ``calibration``: the calibration
    target shown and its label (``world/calibration/target``, and a status line with its
    distance from the EE); ``operator_model``: lines about the operator model the
    certificates are for (the status panel).
    """

    tick: int
    t: float  # s since the daemon started
    link_positions: FloatArray  # (K, 3)
    link_rotations: FloatArray  # (K, 3, 3)
    ee_position: FloatArray  # (3,)
    ee_quaternion: FloatArray  # (4,) [w, x, y, z]
    objects: Mapping[str, tuple[FloatArray, FloatArray]]  # name -> (position, quaternion)
    posterior: Mapping[str, float] | None
    joystick: FloatArray | None
    command: FloatArray  # the EE velocity sent, m/s
    mode: str
    slack: float | None
    committed: str | None
    tick_seconds: float | None = None
    gripper_half_gap: float | None = None
    phase: str | None = None
    operator: str | None = None
    fault: str | None = None
    stage: str | None = None
    placement: tuple[str, ...] | None = None
    corrections: Mapping[str, tuple[FloatArray, FloatArray]] | None = None
    calibration: tuple[tuple[float, float, float], str] | None = None
    operator_model: tuple[str, ...] | None = None
