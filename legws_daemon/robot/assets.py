"""The Sawyer robot description, fetched once with pip at set-up and cached on disk.

The MJCF and meshes come from robosuite's wheel on PyPI (MIT licence), which ships a
standalone ``robots/sawyer`` folder. robosuite itself is never installed (it pins an old
mink): the wheel is downloaded with ``pip download --no-deps`` and only that folder is
unpacked into the asset cache. Nothing is downloaded at run time.

Cache location: ``$LEGWS_ASSETS``, else ``.assets/`` in a source checkout, else
``~/.cache/legws/assets``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

from legws_daemon.errors import InputError, LegwsError

ROBOSUITE_VERSION = "1.5.2"
_PREFIX = "robosuite/models/assets/robots/sawyer/"
_MARKER = "legws-asset.json"
FETCH_COMMAND = "./dev setup   (or: legws assets fetch)"


def assets_dir() -> Path:
    env = os.environ.get("LEGWS_ASSETS")
    if env:
        return Path(env)
    repo = Path(__file__).resolve().parents[2]
    if (repo / "pyproject.toml").is_file():
        return repo / ".assets"
    return Path.home() / ".cache" / "legws" / "assets"


def sawyer_dir(root: Path | None = None) -> Path:
    """Folder holding ``robot.xml`` and its meshes.

    Raises:
        InputError: one line saying which command fetches the model when it is missing.
    """
    d = (root or assets_dir()) / "sawyer"
    marker = d / _MARKER
    if not (d / "robot.xml").is_file() or not marker.is_file():
        raise InputError(f"the Sawyer model is not in {d}; fetch it with: {FETCH_COMMAND}")
    return d


def fetch(root: Path | None = None, *, force: bool = False) -> Path:
    """Download robosuite's wheel with pip and unpack its Sawyer folder into the cache.

    Atomic: the folder appears complete or not at all.
    """
    root = root or assets_dir()
    target = root / "sawyer"
    if not force:
        try:
            return sawyer_dir(root)
        except InputError:
            pass
    root.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=root, prefix=".fetch-") as tmp:
        cmd = [
            sys.executable, "-m", "pip", "download", "--no-deps", "--quiet",
            "--disable-pip-version-check", f"robosuite=={ROBOSUITE_VERSION}", "-d", tmp,
        ]  # fmt: skip
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        wheels = list(Path(tmp).glob("robosuite-*.whl"))
        if proc.returncode != 0 or not wheels:
            last = (proc.stderr.strip().splitlines() or ["no wheel downloaded"])[-1]
            raise LegwsError(f"pip download of robosuite=={ROBOSUITE_VERSION} failed: {last}")
        staging = Path(tmp) / "sawyer"
        with zipfile.ZipFile(wheels[0]) as wheel:
            members = [n for n in wheel.namelist() if n.startswith(_PREFIX) and not n.endswith("/")]
            for name in members:
                dest = staging / name[len(_PREFIX) :]
                dest.parent.mkdir(parents=True, exist_ok=True)
                with wheel.open(name) as src, dest.open("wb") as out:
                    shutil.copyfileobj(src, out)
        (staging / _MARKER).write_text(
            json.dumps({"source": f"robosuite=={ROBOSUITE_VERSION}", "files": len(members)})
        )
        if target.exists():
            shutil.rmtree(target)
        staging.rename(target)
    return sawyer_dir(root)
