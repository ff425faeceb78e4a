"""legws: legible workspaces for shared autonomy.

The package is layered: ``core`` holds the pure mathematics (geometry, observer,
certificate, Monte Carlo check), ``scene`` the object/grasp/layout model,
``formats`` every file format with its validation, and ``cli`` the ``legws``
command. Nothing in ``core`` performs I/O.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("legws")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0"

__all__ = ["__version__"]
