"""legws: legible workspaces for shared autonomy.

The package is layered: ``core`` holds the pure mathematics (geometry, observer,
certificate, Monte Carlo check), ``scene`` the object/grasp/layout model,
``formats`` every file format with its validation, and ``cli`` the ``legws``
command. Nothing in ``core`` performs I/O.
"""

import os
from importlib.metadata import PackageNotFoundError, version

# MuJoCo picks its OpenGL backend once, when first imported: headless EGL unless the user
# chose another (MUJOCO_GL=osmesa or glfw). Set here, before any module of the package can
# import mujoco, so that the CLI, benchmarks and library users all render offscreen.
os.environ.setdefault("MUJOCO_GL", "egl")

try:
    __version__ = version("legws")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0"

__all__ = ["__version__"]
