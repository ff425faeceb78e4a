"""Calibration reaches of a simulated operator, offline (no daemon, no robot): the EE moves
exactly as the deflection says (``x += v_max dt u``), what the fit of method.md §10 sees
from a perfect velocity-controlled arm. Used by the tests of the fit and by
``benchmarks/operator_validity.py``; the end-to-end calibration over zenoh
(``legws operator calibrate`` with ``legws joystick sim-user``) drives the MuJoCo
stand-in instead."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.calibration import ARRIVED, CalibrationBox, calibration_targets
from legws_daemon.core.geometry import FloatArray
from legws_daemon.core.params import Params
from legws_daemon.core.user_model import OperatorStick, SimulatedUser

#: The box of the stand-in's workspace (every scene shares it, method.md §7) with its
#: objects at most 12 cm tall and the EE home 30 cm above the table.
STAND_IN_BOX = CalibrationBox.above_table((0.30, 0.85), (-0.45, 0.45), 0.0, 0.12, 0.30)
HOME = (0.55, 0.0, 0.30)
#: A reach that has not arrived after this many seconds is cut there.
REACH_LIMIT_S = 60.0


def simulate_reaches(
    user: SimulatedUser,
    reaches: int,
    rng: np.random.Generator,
    params: Params | None = None,
    *,
    box: CalibrationBox = STAND_IN_BOX,
    start: ArrayLike = HOME,
) -> list[tuple[FloatArray, FloatArray, FloatArray]]:
    """``reaches`` calibration reaches ``(ee (n, 3), u (n, 3), target (3,))``, chained (each
    starts where the last ended), each until the EE is within
    :data:`~legws_daemon.core.calibration.ARRIVED` of its target."""
    params = params or Params()
    stick = OperatorStick(user, params, rng)
    here = np.asarray(start, dtype=np.float64).copy()
    out = []
    limit = int(REACH_LIMIT_S / params.dt)
    for target in calibration_targets(reaches, box, here, rng):
        stick.reset()
        ee, us = [], []
        for _ in range(limit):
            if np.linalg.norm(target - here) < ARRIVED:
                break
            u = stick.deflection(here, target)
            ee.append(here.copy())
            us.append(u)
            here = here + params.v_max * params.dt * u
        out.append((np.array(ee).reshape(-1, 3), np.array(us).reshape(-1, 3), target))
    return out
