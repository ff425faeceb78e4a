"""Screenshots of web pages in Debian's Chromium (/usr/bin/chromium), driven by playwright,
and the checks that the tools the rendering tests need are here (:func:`require`).

No browser is downloaded: playwright launches the system's Chromium, headless, rendering
WebGL in software (SwiftShader), with a fresh temporary profile and no
background traffic (no updates, sync or QUIC). The Rerun web viewer's wasm takes 15-20 s
to load on a 2-core machine, so a page is polled with screenshots until a test's
``ready`` check on the pixels passes, never waited for with a fixed sleep.
"""

from __future__ import annotations

import io
import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from PIL import Image

CHROMIUM = Path("/usr/bin/chromium")
FLAGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--enable-unsafe-swiftshader",
    "--use-angle=swiftshader",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
#: Seconds between two screenshots of a page that is not ready yet.
POLL = 2.0


def chromium_missing() -> str:
    """Why Chromium cannot be driven here ("" when it can), for a skip or fail message."""
    if not (CHROMIUM.is_file() and os.access(CHROMIUM, os.X_OK)):
        return f"no Chromium at {CHROMIUM} (Debian package chromium)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "python playwright is not installed (pip install playwright)"
    return ""


def chromium_available() -> bool:
    """Whether Debian's Chromium and python playwright are installed."""
    return not chromium_missing()


def chromium_screenshot(
    url: str,
    out: Path,
    *,
    size: tuple[int, int] = (1280, 800),
    ready: Callable[[np.ndarray], bool],
    timeout: float = 90.0,
) -> np.ndarray:
    """Open ``url`` and screenshot it every :data:`POLL` s until ``ready(rgb)`` holds.

    Returns:
        The last screenshot as an RGB ``uint8`` array (height, width, 3), also saved as the
        PNG ``out``.

    Raises:
        AssertionError: on timeout, naming ``out``, where the last screenshot is saved.
    """
    from playwright.sync_api import TimeoutError as PlaywrightTimeout
    from playwright.sync_api import sync_playwright

    png = b""
    deadline = time.monotonic() + timeout
    with sync_playwright() as p:
        # launch() gives the browser a fresh temporary profile, removed when it closes
        browser = p.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=FLAGS)
        try:
            page = browser.new_page(viewport={"width": size[0], "height": size[1]})
            page.goto(url, wait_until="load", timeout=timeout * 1000)
            while True:
                # a page busy compiling the viewer's wasm on a loaded machine can take more
                # than playwright's default 30 s to screenshot: wait, up to the deadline
                left = max(deadline - time.monotonic(), 1.0)
                try:
                    png = page.screenshot(timeout=left * 1000)
                except PlaywrightTimeout:
                    break
                rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
                if ready(rgb):
                    out.write_bytes(png)
                    return rgb
                if time.monotonic() > deadline:
                    break
                time.sleep(POLL)
        finally:
            browser.close()
    out.write_bytes(png)
    raise AssertionError(
        f"the page {url} was not ready within {timeout:g} s; last screenshot: {out}"
    )


def vulkan_missing() -> str:
    """Why the headless native viewer cannot render here ("" when it can): it needs a
    Vulkan driver, in software Mesa's lavapipe (Debian package mesa-vulkan-drivers)."""
    folders = [Path("/usr/share/vulkan/icd.d"), Path("/etc/vulkan/icd.d")]
    if not any(f.is_dir() and any(f.glob("*.json")) for f in folders):
        return "no Vulkan driver (Debian package mesa-vulkan-drivers)"
    return ""


def require(missing: str) -> None:
    """Skip a test whose tool is missing, with the reason; fail instead where the tools must
    be there (``CI`` or ``LEGWS_REQUIRE_BROWSER`` set), so it never passes silently."""
    if not missing:
        return
    import pytest

    if os.environ.get("CI") or os.environ.get("LEGWS_REQUIRE_BROWSER"):
        pytest.fail(f"required here (CI or LEGWS_REQUIRE_BROWSER is set): {missing}")
    pytest.skip(missing)
