"""Drive one pick through a running daemon (legws daemon --profile sim --scene desk first):
steer straight at a goal until the robot commits, then hold the enable button, hands off,
while it finishes; print what happened."""

import sys

import numpy as np

from legws_daemon.client import Client
from legws_daemon.formats.messages import Buttons

profile = sys.argv[1] if len(sys.argv) > 1 else "sim"  # a profile name or .toml path
goal = sys.argv[2] if len(sys.argv) > 2 else "white_mug"
with Client.from_profile(profile) as daemon, daemon.joystick("example") as stick:
    first = daemon.status()  # waits for the daemon; one line if there is none
    print("daemon up since", first.started, "- targets:", ", ".join(first.targets))
    for s in daemon.statuses(timeout=5.0):  # 10 Hz: faster than the 0.25 s deadman
        axes = (0.0, 0.0, 0.0)  # after the commit: hands off, the robot finishes
        if s.mode == "teleop" and s.ee is not None:
            to_goal = np.array(s.targets[goal]) - np.array(s.ee.position)
            axes = tuple(to_goal / max(float(np.linalg.norm(to_goal)), 0.05))
        stick.publish(axes, Buttons(enable=True))
        if s.mode == "idle":  # the task is done
            break
    for event in daemon.events(timeout=1.0):  # (events and status come on their own keys)
        print(event.kind, {k: v for k, v in event.detail.items() if k != "posterior"})
