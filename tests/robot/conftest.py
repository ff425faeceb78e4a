"""Set-up of the simulation tests: MuJoCo renders offscreen with EGL unless told otherwise.

MuJoCo reads ``MUJOCO_GL`` once, when first imported, so this runs at import time (the
CLI does the same in ``legws_daemon.cli.main``).
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")
