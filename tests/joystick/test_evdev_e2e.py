"""A gamepad drives the stand-in end to end: evdev events of an Xbox pad (the only fake: the
device node, see :mod:`tests.joystick.fake_evdev`) -> the shipped ``xbox`` mapping -> the
evdev reader -> a real publisher -> zenoh loopback -> the daemon in its own process.

The hold-to-run button decides everything: the stick without LB moves nothing and claims no
lease; with LB the person steers to the mug and the daemon commits to it; after the commit
the arm finishes only while LB is held (released, it stands still, however long); the
publisher's goodbye ends the lease.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from evdev import ecodes

from legws_daemon.formats.input_mapping import load_mapping_named
from legws_daemon.formats.profile import TransportSpec
from legws_daemon.joystick.evdev_input import EvdevReader, run_evdev
from legws_daemon.joystick.publisher import Publisher
from legws_daemon.transport.session import config_from_spec, keys
from tests.daemon.procs import Monitor, monitor, ready, start, stop, write_profile
from tests.joystick.fake_evdev import FakeInputDir, FakeNode, xbox_pad
from tests.net import free_port

ROBOT = "sawyer_sim"
pytestmark = pytest.mark.slow
_, XBOX = load_mapping_named("xbox")
FULL = 32767


def stick_for(direction: np.ndarray, strength: float = 0.8) -> dict[int, int]:
    """Raw stick values whose mapped deflection (deadzone 0.15, quadratic, inverted axes)
    is ``strength`` times the unit ``direction`` in the base frame."""
    unit = direction / max(float(np.linalg.norm(direction)), 1e-9)
    raw = []
    for out in strength * unit:
        magnitude = 0.0 if abs(out) < 1e-6 else 0.15 + 0.85 * math.sqrt(abs(out))
        raw.append(math.copysign(magnitude, out))
    # x <- -ABS_Y, y <- -ABS_X, z <- -ABS_RY (stick up and left report negative values)
    return {
        ecodes.ABS_Y: round(-raw[0] * FULL),
        ecodes.ABS_X: round(-raw[1] * FULL),
        ecodes.ABS_RY: round(-raw[2] * FULL),
    }


class Person:
    """Holds the pad: LB (enable) and the left/right sticks, from the test's thread."""

    def __init__(self, pad: FakeNode) -> None:
        self.pad = pad

    def hold(self, enable: bool) -> None:
        self.pad.frame((ecodes.EV_KEY, ecodes.BTN_TL, int(enable)))

    def stick(self, values: dict[int, int]) -> None:
        self.pad.frame(*((ecodes.EV_ABS, code, v) for code, v in values.items()))

    def center(self) -> None:
        self.stick(dict.fromkeys((ecodes.ABS_X, ecodes.ABS_Y, ecodes.ABS_RY), 0))


@pytest.fixture
def pad(tmp_path: Path) -> Iterator[tuple[FakeInputDir, FakeNode]]:
    folder = tmp_path / "input"
    folder.mkdir()
    devices = FakeInputDir(folder)
    node = xbox_pad()
    devices.plug(0, node)
    try:
        yield devices, node
    finally:
        devices.close_all()


def ee(m: Monitor) -> np.ndarray:
    s = m.latest()
    assert s is not None and s["ee"] is not None
    return np.array(s["ee"]["position"])


def test_a_gamepad_with_hold_to_run_drives_the_stand_in_to_a_commit_and_through_it(
    tmp_path: Path, pad: tuple[FakeInputDir, FakeNode]
) -> None:
    devices, node = pad
    person = Person(node)
    port = free_port()
    profile = write_profile(tmp_path, "sim", port)
    daemon = start(
        ["daemon", "--profile", str(profile), "--scene", "desk", "--duration", "150"],
        tmp_path / "daemon.log",
    )
    spec = TransportSpec(listen=[], connect=[f"tcp/127.0.0.1:{port}"])
    stop_publishing = threading.Event()
    lines: list[str] = []
    try:
        with monitor(port, ROBOT) as m:
            assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()
            mug = np.array(m.latest()["targets"]["white_mug"])  # type: ignore[index]
            reader = EvdevReader(XBOX, folder=devices.folder, opener=devices.open, log=lines.append)
            pub = Publisher(config_from_spec(spec), keys(ROBOT)["joystick"], source="pad")
            with reader, pub:
                worker = threading.Thread(
                    target=run_evdev, args=(pub, reader),
                    kwargs={"rate": 20.0, "stop_event": stop_publishing}, daemon=True,
                )  # fmt: skip
                worker.start()
                assert pub.wait_matched(5.0)

                # 1. the stick without LB: nothing moves, nobody is the operator
                p0 = ee(m)
                person.stick(stick_for(mug - p0))
                time.sleep(1.5)
                s = m.latest()
                assert s is not None
                assert s["deadman"] is True and s["operator"] is None
                np.testing.assert_allclose(ee(m), p0, atol=1e-6)

                # 2. LB held: the person steers to the mug until the daemon commits
                person.hold(True)
                deadline = time.monotonic() + 60
                while "commit" not in m.kinds():
                    assert time.monotonic() < deadline, m.latest()
                    person.stick(stick_for(mug - ee(m)))
                    time.sleep(0.1)
                person.center()
                commit = next(e["detail"] for e in m.events if e["kind"] == "commit")
                assert commit["goal"] == "white_mug"
                operator = m.latest()["operator"]  # type: ignore[index]
                assert operator == {"source": "pad", "session": pub.session_id}

                # 3. the arm finishes only while LB is held: released, it stands still
                assert m.wait_for(lambda m: (m.latest() or {}).get("mode") == "assist", 5)
                time.sleep(1.0)
                person.hold(False)
                time.sleep(0.5)  # the deadman (0.25 s) and a status period
                paused = ee(m)
                assert m.latest()["deadman"] is True  # type: ignore[index]
                time.sleep(1.5)
                np.testing.assert_allclose(ee(m), paused, atol=1e-6)
                assert "stage_done" not in m.kinds()
                person.hold(True)
                assert m.wait_for(lambda m: "stage_done" in m.kinds(), 60), m.latest()
                stop_publishing.set()
                worker.join(5.0)
            # 4. the publisher's goodbye ends the lease at once
            assert m.wait_for(lambda m: (m.latest() or {}).get("operator") is None, 5)
            kinds = m.kinds()
    finally:
        code, _ = stop(daemon)
    assert code == 0
    assert kinds.count("commit") == 1 and "cancel" not in kinds
    assert reader.state.frames > 10 and reader.unplugged == 0
