"""Where a calibration sends the operator (method.md §10): targets in free space above the
table, one reach each, every reach long enough to show how the person steers.

A target is a point, not a grasp: the operator steers the EE to within
:data:`ARRIVED` of it (orientation held, as in teleoperation), then the next one appears.
Targets are drawn uniformly in a box over the table — inside the workspace bounds, at
least :data:`CLEARANCE` above the highest object — each at least
:data:`MIN_REACH` from where the previous reach ended, so the reaches run in every
direction, up and down as well as across. Seeded: the same seed, the same targets.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError

#: Within this distance of its target a reach is done, m (twice a pick's arrival at 1 cm:
#: a person steering at 5 cm/s stops there without overshooting).
ARRIVED = 0.02
#: Each target at least this far from where the previous reach ended, m (5 s at full
#: deflection).
MIN_REACH = 0.25
#: Targets at least this far above the highest object on the table, m.
CLEARANCE = 0.08
#: Most targets of one calibration.
MAX_TARGETS = 200


@dataclass(frozen=True, slots=True)
class CalibrationBox:
    """The box targets are drawn in (robot base frame, m)."""

    low: FloatArray
    high: FloatArray

    @classmethod
    def above_table(
        cls,
        x_range: tuple[float, float],
        y_range: tuple[float, float],
        table_height: float,
        highest: float,
        home_height: float,
    ) -> CalibrationBox:
        """Within the workspace's x and y bounds (5 cm inside), from :data:`CLEARANCE`
        above the highest object (``highest``, m above the table; at least 10 cm) up to
        10 cm above the EE home."""
        z_lo = table_height + max(highest + CLEARANCE, 0.10)
        z_hi = max(home_height + 0.10, z_lo + 0.10)
        return cls(
            np.array([x_range[0] + 0.05, y_range[0] + 0.05, z_lo]),
            np.array([x_range[1] - 0.05, y_range[1] - 0.05, z_hi]),
        )


def calibration_targets(
    n: int, box: CalibrationBox, start: ArrayLike, rng: np.random.Generator
) -> list[FloatArray]:
    """``n`` targets in ``box``, the first at least :data:`MIN_REACH` from ``start``, each
    next one that far from the one before (redrawn until it is; the box is far larger).

    Raises:
        InputError: ``n`` outside 2..:data:`MAX_TARGETS`, or a box too small for reaches of
            :data:`MIN_REACH`.
    """
    if not 2 <= n <= MAX_TARGETS:
        raise InputError(f"expected 2 to {MAX_TARGETS} targets, got {n}", field="--targets")
    diagonal = float(np.linalg.norm(box.high - box.low))
    if diagonal < 2 * MIN_REACH:
        raise InputError(
            f"the calibration box is {diagonal:.2f} m across; reaches of {MIN_REACH} m need "
            f"{2 * MIN_REACH} m",
            field="workspace",
        )
    here = np.asarray(start, dtype=np.float64)
    out: list[FloatArray] = []
    for _ in range(n):
        for _attempt in range(10_000):
            target = rng.uniform(box.low, box.high)
            if np.linalg.norm(target - here) >= MIN_REACH:
                break
        else:  # pragma: no cover - the box is checked above
            raise InputError("no target far enough from the last one", field="workspace")
        out.append(target)
        here = target
    return out
