"""The registered arms (the robot descriptions): one module per arm in this package, each
defining ``ARM``.

Adding an arm is one module here (found by its name, nothing else to edit) and, for its
model, the robosuite folder its :class:`~legws_daemon.arms.spec.ArmSpec` names.
Standard library only (the bridges read these tables too).
"""

from __future__ import annotations

import importlib
import pkgutil

from legws_daemon.arms.spec import ArmSpec, Mount

__all__ = ["DEFAULT_ARM", "ArmSpec", "Mount", "arm", "arm_names"]

#: The arm of the paper, and of a profile or command that names none.
DEFAULT_ARM = "sawyer"
_REGISTRY: dict[str, ArmSpec] = {}


def _load() -> dict[str, ArmSpec]:
    if not _REGISTRY:
        for info in sorted(pkgutil.iter_modules(__path__), key=lambda i: i.name):
            if info.name == "spec" or info.name.startswith("_"):
                continue
            module = importlib.import_module(f"{__name__}.{info.name}")
            spec = getattr(module, "ARM", None)
            if not isinstance(spec, ArmSpec) or spec.name != info.name:
                raise RuntimeError(
                    f"{module.__name__} must define ARM = ArmSpec(name={info.name!r})"
                )
            _REGISTRY[spec.name] = spec
    return _REGISTRY


def arm_names() -> tuple[str, ...]:
    """The registered arms' names, sorted (the default first)."""
    names = sorted(_load())
    return tuple(sorted(names, key=lambda n: n != DEFAULT_ARM))


def arm(name: str = DEFAULT_ARM) -> ArmSpec:
    """The arm registered as ``name``.

    Raises:
        KeyError: with the registered names, for a name that is not one.
    """
    found = _load().get(name)
    if found is None:
        raise KeyError(f"unknown arm {name!r}; expected one of: {', '.join(arm_names())}")
    return found
