"""Finding and loading scenes by name.

Scenes live in the repository's ``scenes/`` folder (one ``NAME.toml`` per scene). The
``LEGWS_SCENES`` environment variable points elsewhere.
"""

from __future__ import annotations

import os
from pathlib import Path

from legws_daemon.errors import InputError
from legws_daemon.formats.scene_file import load_scene_spec
from legws_daemon.formats.validation import did_you_mean
from legws_daemon.scene.scene import Scene

_REPO = Path(__file__).resolve().parents[2]


def scenes_dir() -> Path:
    env = os.environ.get("LEGWS_SCENES")
    return Path(env) if env else _REPO / "scenes"


def scene_names(directory: Path | None = None) -> list[str]:
    d = directory or scenes_dir()
    return sorted(p.stem for p in d.glob("*.toml"))


def load_scene(name_or_path: str | Path, directory: Path | None = None) -> Scene:
    """Load a scene by name (from the scenes folder) or from a ``.toml`` path.

    An unknown name lists the known ones, and says ``did you mean 'desk'?`` for a close
    one."""
    text = str(name_or_path)
    if text.endswith(".toml") or os.sep in text:
        path = Path(text)
    else:
        d = directory or scenes_dir()
        path = d / f"{text}.toml"
        if not path.is_file():
            names = scene_names(d)
            guess = did_you_mean(text, names)
            hint = f"; did you mean '{guess}'?" if guess is not None else ";"
            known = ", ".join(names) or "(none)"
            raise InputError(f"unknown scene {text!r}{hint} known: {known}", field="scene")
    return Scene(load_scene_spec(path), str(path))
