"""The package layout is the architecture: no package imports one above it.

Read from the source with ``ast`` (every ``import``/``from ... import`` of a
``legws_daemon`` module, at any depth, type-checking imports included), so a lazy import
inside a function counts too.
"""

from __future__ import annotations

import ast
import functools
from collections import defaultdict
from pathlib import Path

import pytest

PACKAGE = Path(__file__).parents[1] / "legws_daemon"

#: Bottom to top. A package may import only packages listed before it (and itself); the
#: top-level modules (``errors``, ``workers``, ``__init__``) sit below everything.
LAYERS = [
    "arms",  # the robot descriptions: data, standard library only (the bridges read them)
    "core",  # the method's math: geometry, observer, certificate
    "formats",  # file and message schemas, validation
    "safety",  # the envelope: pure math on commands
    "scene",  # scenes, grasps, layouts
    "robot",  # the robot model: world, kinematics, IK, feasibility, the motion planner
    "task",  # task graphs, actions, plans
    "transport",  # zenoh sessions
    "hardware",  # adapters
    "telemetry",  # Rerun
    "autonomy",  # the shared-autonomy state machine
    "daemon",  # the service around it
    "joystick",  # publishers and the simulated user
    "client",  # a client library for labs: status, events, commands, a joystick
    "tracking",  # a camera tracker of the objects: fiducial markers, the sim camera
    "design",  # layout optimisation and stage plans
    "placement",  # printable placement mats of planned layouts
    "sim",  # the paper's protocol on the stand-in
    "demo",
    "study",  # user studies: protocols, counterbalanced schedules
    "cli",
]
TOP_LEVEL = {"errors", "workers", "__init__", "__main__"}


@functools.cache
def imports() -> dict[str, set[str]]:
    """Package -> the legws packages its modules import (read once per test process: every
    test below asks)."""
    edges: dict[str, set[str]] = defaultdict(set)
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE)
        if len(rel.parts) == 1:
            continue  # a top-level module
        package = rel.parts[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names: list[str] = []
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            for name in names:
                parts = name.split(".")
                if parts[0] != "legws_daemon" or len(parts) < 2 or parts[1] in TOP_LEVEL:
                    continue
                if parts[1] != package:
                    edges[package].add(parts[1])
    return dict(edges)


def test_every_package_has_a_layer() -> None:
    packages = {p.name for p in PACKAGE.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert packages == set(LAYERS)


@pytest.mark.parametrize("package", LAYERS)
def test_a_package_imports_only_the_layers_below_it(package: str) -> None:
    below = set(LAYERS[: LAYERS.index(package)])
    assert imports().get(package, set()) <= below, sorted(imports()[package] - below)


def test_the_daemon_and_the_adapters_do_not_import_the_protocol() -> None:
    edges = imports()
    for package in ("daemon", "hardware", "autonomy"):
        assert "sim" not in edges.get(package, set()), package
