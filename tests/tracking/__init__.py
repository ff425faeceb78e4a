"""Tests of the camera tracker. The sim camera renders offscreen with EGL unless told
otherwise (MuJoCo reads ``MUJOCO_GL`` once, when first imported)."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")
