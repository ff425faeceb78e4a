"""The operator's browser view: `legws daemon --rerun web:PORT` on the sim profile, the page
opened in a real headless Chromium, and the Sawyer found drawn in the 3D view by its pixels.

The Sawyer's links are red (its material colour, (1, 0, 0)); nothing else in the tea scene
is, and the web viewer's background and the table are not: a few thousand strongly red
pixels in the 3D view (the left 60 % of the page, above the log) are the arm's meshes.
"""

from __future__ import annotations

import re
import socket
import time
from pathlib import Path

import numpy as np
import pytest

from tests.browser import chromium_missing, chromium_screenshot, require
from tests.daemon.procs import start, stop, write_profile
from tests.net import free_port, free_port_pair

pytestmark = pytest.mark.slow

#: Strongly red pixels in the 3D view that mean "the arm is drawn" (it covers ~20,000 of
#: the 1600x1000 page when drawn; 0 before the viewer has loaded).
ARM_PIXELS = 3000


def arm_pixels(rgb: np.ndarray) -> int:
    h, w, _ = rgb.shape
    view = rgb[: int(h * 0.75), : int(w * 0.6)].astype(int)
    return int(((view[..., 0] > 140) & (view[..., 1] < 70) & (view[..., 2] < 70)).sum())


def _wait_for_url(log: Path, timeout: float = 60.0) -> str:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = re.search(r"watch in a browser: (\S+)", log.read_text(errors="replace"))
        if found:
            return found.group(1)
        time.sleep(0.2)
    raise AssertionError(f"no URL printed: {log.read_text(errors='replace')[-2000:]}")


def test_the_browser_shows_the_arm_of_a_running_daemon(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    require(chromium_missing())
    monkeypatch.setenv("RERUN_TELEMETRY_ENABLED", "false")
    zenoh_port, web = free_port(), free_port_pair()
    profile = write_profile(tmp_path, "sim", zenoh_port)
    log = tmp_path / "daemon.log"
    rrd = tmp_path / "session.rrd"
    daemon = start(["daemon", "--profile", str(profile), "--scene", "tea", "--duration", "400",
                    "--rerun", f"web:{web}", "--rerun", f"save:{rrd}"], log)  # fmt: skip
    try:
        url = _wait_for_url(log)
        assert url == (
            f"http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{web + 1}%2Fproxy"
        )
        rgb = chromium_screenshot(url, tmp_path / "page.png", size=(1600, 1000),
                                  ready=lambda px: arm_pixels(px) > ARM_PIXELS,
                                  timeout=300)  # fmt: skip
        assert arm_pixels(rgb) > ARM_PIXELS
        # the arm is in the 3D view, not in the plots on the right
        right = rgb[:, int(rgb.shape[1] * 0.62) :].astype(int)
        assert ((right[..., 0] > 140) & (right[..., 1] < 70) & (right[..., 2] < 70)).sum() < 500
    finally:
        code, _ = stop(daemon, timeout=30)
    assert code == 0, log.read_text(errors="replace")[-2000:]
    # the web viewer went with the daemon; the recording beside it is whole
    with socket.socket() as s:
        assert s.connect_ex(("127.0.0.1", web)) != 0
    assert rrd.stat().st_size > 1_000_000  # the meshes are in it
