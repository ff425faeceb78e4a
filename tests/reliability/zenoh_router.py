"""A zenoh router for the fault tests: ``python -m tests.reliability.zenoh_router ENDPOINT``.

``zenohd`` is not installed here; a Python session in ``router`` mode routes between
clients the same way. It listens on ENDPOINT only (multicast scouting off), prints
``ready`` once open, and closes its session on SIGTERM or SIGINT.
"""

from __future__ import annotations

import json
import signal
import sys
import threading
from types import FrameType

import zenoh


def router_config(endpoint: str) -> zenoh.Config:
    """Router mode, listening on ``endpoint`` only, no scouting."""
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"router"')
    cfg.insert_json5("listen/endpoints", json.dumps([endpoint]))
    cfg.insert_json5("connect/endpoints", "[]")
    cfg.insert_json5("scouting/multicast/enabled", "false")
    return cfg


def main() -> None:
    endpoint = sys.argv[1]
    stop = threading.Event()

    def handler(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGINT, handler)
    with zenoh.open(router_config(endpoint)):
        print("ready", flush=True)
        stop.wait(600)  # bounded: a forgotten router ends by itself


if __name__ == "__main__":
    main()
