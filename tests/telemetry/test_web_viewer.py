"""``--rerun web[:[HOST:]PORT]``: the target's forms, and the ``rerun --serve-web`` child:
on 127.0.0.1 only, a taken port refused in one line, gone after close, and a browser that
opens the page sees what an SDK logged into it."""

from __future__ import annotations

import contextlib
import socket
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import psutil
import pytest
import rerun as rr
import rerun.blueprint as rrb

from legws_daemon.errors import InputError
from legws_daemon.telemetry.web_viewer import (
    WebTarget,
    WebViewer,
    accepting,
    parse_web_target,
    port_free,
)
from tests.browser import chromium_missing, chromium_screenshot, require
from tests.net import free_port_pair


def free_target() -> WebTarget:
    """A target on 127.0.0.1 whose page port and the next (gRPC) are both free."""
    return parse_web_target(str(free_port_pair()))


@pytest.fixture
def viewer() -> Iterator[WebViewer]:
    with WebViewer.start(free_target()) as v:
        yield v


# --- the target ------------------------------------------------------------------------


def test_bare_web_is_loopback_9090_and_grpc_on_the_next_port() -> None:
    target = parse_web_target(None)
    assert target == WebTarget("127.0.0.1", 9090, 9091)
    assert target.grpc_url == "rerun+http://127.0.0.1:9091/proxy"
    assert target.page_url == (
        "http://127.0.0.1:9090/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A9091%2Fproxy"
    )


@pytest.mark.parametrize(
    ("arg", "expected"),
    [
        ("8000", WebTarget("127.0.0.1", 8000, 8001)),
        ("localhost:8000", WebTarget("127.0.0.1", 8000, 8001)),
        ("127.0.0.1:1", WebTarget("127.0.0.1", 1, 2)),
        ("10.1.2.3:65534", WebTarget("10.1.2.3", 65534, 65535)),
    ],
)
def test_port_and_host_forms(arg: str, expected: WebTarget) -> None:
    assert parse_web_target(arg) == expected


def test_urls_never_say_localhost() -> None:
    target = parse_web_target("localhost:8000")
    assert "localhost" not in target.page_url + target.grpc_url
    assert target.page_url.startswith("http://127.0.0.1:8000/?url=")


@pytest.mark.parametrize(
    "arg",
    ["", "abc", "0", "65535", "70000", "-1", "80.5", "127.0.0.1", "127.0.0.1:", ":8000",
     "example.com:8000", "1.2.3:8000", "::1:8000", "256.0.0.1:8000", "١٢٣"],
)  # fmt: skip
def test_bad_targets_are_one_line_naming_the_option(arg: str) -> None:
    with pytest.raises(InputError) as info:
        parse_web_target(arg)
    text = str(info.value)
    assert "\n" not in text
    assert text.startswith("--rerun: ")
    assert "web:PORT" in text


def test_the_option_named_can_be_chosen() -> None:
    with pytest.raises(InputError, match=r"^--web: "):
        parse_web_target("x", field="--web")


# --- the child -------------------------------------------------------------------------


def _web_viewers() -> list[psutil.Process]:
    """The ``rerun --serve-web`` children of this process still running."""
    found = []
    for child in psutil.Process().children(recursive=True):
        with contextlib.suppress(psutil.Error):
            if child.status() != psutil.STATUS_ZOMBIE and "--serve-web" in child.cmdline():
                found.append(child)
    return found


def _listening(port: int) -> set[str]:
    """The local addresses (hex, as /proc/net/tcp writes them) listening on ``port``."""
    found = set()
    for table in (Path("/proc/net/tcp"), Path("/proc/net/tcp6")):
        for line in table.read_text().splitlines()[1:]:
            fields = line.split()
            address, hex_port = fields[1].split(":")
            if fields[3] == "0A" and int(hex_port, 16) == port:  # 0A: LISTEN
                found.add(address)
    return found


def test_it_listens_on_127_0_0_1_only(viewer: WebViewer) -> None:
    target = viewer.target
    for port in (target.web_port, target.grpc_port):
        assert _listening(port) == {"0100007F"}  # 127.0.0.1, little-endian hex
        assert accepting("127.0.0.1", port)
        assert not accepting("127.0.0.2", port)  # another address of this machine


def test_the_page_is_served_on_127_0_0_1_only(viewer: WebViewer) -> None:
    port = viewer.target.web_port
    with urllib.request.urlopen(viewer.target.page_url, timeout=10) as answer:
        assert answer.status == 200
        assert b"rerun" in answer.read().lower()
    with pytest.raises(urllib.error.URLError):
        urllib.request.urlopen(f"http://127.0.0.2:{port}/", timeout=5)


@pytest.mark.parametrize("which", ["web_port", "grpc_port"])
def test_a_taken_port_is_refused_in_one_line(which: str) -> None:
    target = free_target()
    taken = getattr(target, which)
    with socket.socket() as squatter:
        squatter.bind(("127.0.0.1", taken))
        squatter.listen()
        with pytest.raises(InputError) as info:
            WebViewer.start(target)
        assert not _web_viewers()
    text = str(info.value)
    assert "\n" not in text
    assert text.startswith("--rerun: ")
    assert f"port {taken} " in text and "already in use" in text


def test_a_child_that_exits_early_is_reported_with_its_error_line() -> None:
    target = free_target()
    with pytest.raises(InputError) as info:
        WebViewer.start(target, memory_limit="lots")
    text = str(info.value)
    assert "\n" not in text
    assert "exited" in text and "memory-limit" in text and "lots" in text
    assert port_free("127.0.0.1", target.web_port)
    assert not _web_viewers()


def test_close_stops_the_child_and_frees_the_ports() -> None:
    target = free_target()
    viewer = WebViewer.start(target)
    pid, log = viewer.pid, viewer.log
    assert viewer.running and log.is_file()
    viewer.close()
    assert not viewer.running
    assert not psutil.pid_exists(pid)
    assert not log.parent.exists()
    for port in (target.web_port, target.grpc_port):
        assert not accepting("127.0.0.1", port)
    viewer.close()  # idempotent


# --- in a browser ----------------------------------------------------------------------

MAGENTA = np.array([255, 0, 255])
_CUBE_FACES = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1),
               (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]  # fmt: skip


def _log_magenta_box(target: WebTarget) -> rr.RecordingStream:
    """Log into the viewer a solid magenta box, alone in a 3D view."""
    rec = rr.RecordingStream("legws-web-viewer-test", recording_id="magenta-box")
    rec.connect_grpc(target.grpc_url)
    rec.send_blueprint(
        rrb.Blueprint(rrb.Spatial3DView(origin="/world", name="3D"), collapse_panels=True)
    )
    h = 1.0
    corners = [[x, y, z] for x in (-h, h) for y in (-h, h) for z in (-h, h)]
    rec.log(
        "world/box",
        rr.Mesh3D(
            vertex_positions=np.array(corners, np.float32),
            triangle_indices=np.array(_CUBE_FACES, np.uint32),
            albedo_factor=[255, 0, 255],
        ),
        static=True,
    )
    rec.log(
        "world/corners", rr.Points3D([[-1.6, -1.6, -1.6], [1.6, 1.6, 1.6]], radii=0.01), static=True
    )
    rec.flush()
    return rec


def magenta_pixels(rgb: np.ndarray) -> np.ndarray:
    """Where a picture shows the box's magenta, shaded by the lights: R and B alike and
    strong, G low."""
    a = rgb.astype(int)
    r, g, b = a[..., 0], a[..., 1], a[..., 2]
    mask: np.ndarray = (r > 120) & (b > 120) & (g < 0.35 * np.minimum(r, b)) & (abs(r - b) < 50)
    return mask


@pytest.mark.slow
def test_a_browser_shows_what_an_sdk_logged(tmp_path: Path) -> None:
    require(chromium_missing())
    width, height = 1280, 800
    # the 3D view: below the top bar (~40 px), above the time panel (~30 px)
    view = (slice(50, height - 40), slice(0, width))
    needed = 0.02 * (height - 90) * width  # ~18000 px; the box covers ~40000
    with WebViewer.start(free_target()) as viewer:
        rec = _log_magenta_box(viewer.target)
        try:
            started = time.monotonic()
            rgb = chromium_screenshot(
                viewer.target.page_url,
                tmp_path / "page.png",
                size=(width, height),
                ready=lambda rgb: magenta_pixels(rgb)[view].sum() > needed,
                timeout=180,  # ~25 s on an idle 2-core machine, ~50 s when busy
            )
            print(f"page ready in {time.monotonic() - started:.1f} s")
        finally:
            rec.disconnect()
    inside = int(magenta_pixels(rgb)[view].sum())
    assert inside > needed
    # all of it in the view: nothing in the top bar (40 px) or the time panel (30 px); the
    # view's margins above are wider, and a box the viewer frames large fills them
    panels = magenta_pixels(rgb)[np.r_[0:40, height - 30 : height]]
    assert panels.sum() < 0.01 * inside
    assert (tmp_path / "page.png").stat().st_size > 0
