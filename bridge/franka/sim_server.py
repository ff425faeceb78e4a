#!/usr/bin/env python3
"""franka-sim as the Franka bridge's robot, on one loopback address only.

Runs in ``.venv-franka-sim`` (``bridge/franka/setup-venvs.sh``). franka-sim's own command
(``run-franka-sim-server``) binds every interface and loads its FR3 model from GitHub at
first use; this serves the same simulator (``franka_sim.FrankaSimServer``: the libfranka
protocol on TCP 1337, the gripper's on 1338, the robot state over UDP, MuJoCo physics at
1 kHz) on the address given, with the Panda's MJCF from robosuite's wheel that the set-up
unpacked (``$FR3_MJCF`` overrides it). libfranka always dials port 1337, so two simulators
on one machine take two loopback addresses (127.0.0.0/8).

Usage: .venv-franka-sim/bin/python bridge/franka/sim_server.py --host 127.0.0.1
Prints ``franka-sim ready on HOST`` once it listens; SIGTERM or SIGINT stops it.
"""

from __future__ import annotations

import argparse
import ipaddress
import logging
import os
import signal
import sys
import threading
from pathlib import Path


def main() -> int:
    parser = argparse.ArgumentParser(prog="sim_server.py", description=__doc__.splitlines()[0])
    parser.add_argument("--host", default="127.0.0.1", help="a loopback address to serve on")
    parser.add_argument("--no-gripper", action="store_true", help="no Franka Hand server")
    parser.add_argument("--verbose", action="store_true", help="franka-sim's INFO lines")
    args = parser.parse_args()
    if not ipaddress.ip_address(args.host).is_loopback:
        parser.error(f"--host must be a loopback address, got {args.host}")
    model = Path(sys.prefix) / "share" / "legws-panda" / "robot.xml"
    if "FR3_MJCF" not in os.environ:
        if not model.is_file():
            parser.error(f"no robot model at {model}: run bridge/franka/setup-venvs.sh")
        os.environ["FR3_MJCF"] = str(model)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    from franka_sim import FrankaSimServer

    server = FrankaSimServer(host=args.host, enable_gripper=not args.no_gripper)
    done = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        done.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    # start() blocks (it runs the physics loop); it runs in a thread so a signal stops it
    runner = threading.Thread(target=server.start, name="franka-sim", daemon=True)
    runner.start()
    while not done.is_set() and runner.is_alive():
        if getattr(server, "running", False) and getattr(server, "server_socket", None):
            print(f"franka-sim ready on {args.host}", flush=True)
            break
        done.wait(0.05)
    while runner.is_alive() and not done.wait(0.1):
        pass
    died = not done.is_set()
    server.stop()
    if died:
        print("franka-sim stopped by itself (see its log above)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
