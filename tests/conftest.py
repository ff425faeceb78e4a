"""Test-wide set-up: library caches and analytics go to a temporary folder, never $HOME."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

_TMP = Path(tempfile.mkdtemp(prefix="legws-tests-"))
for var in ("XDG_CACHE_HOME", "XDG_CONFIG_HOME", "XDG_DATA_HOME"):
    os.environ[var] = str(_TMP / var.lower())
os.environ["MESA_SHADER_CACHE_DIR"] = str(_TMP / "mesa")
os.environ.setdefault("MPLCONFIGDIR", str(_TMP / "mpl"))
# Rerun sends no analytics when CI is set; tests never talk to the internet.
os.environ.setdefault("CI", "true")
