#!/usr/bin/env python3
"""Generate the Python classes of the Intera messages the bridge uses (``intera_core_msgs``).

The ``.msg`` files next to this script are Intera's own (``RethinkRobotics/intera_common``,
release 5.3.0, Apache 2.0), so the classes have Intera's MD5 sums and talk to a real Sawyer
as well as to the simulated one (``sim_sawyer.py``). On the robot's PC the Intera SDK
workspace provides ``intera_core_msgs`` and this is not needed.

Needs Debian's ``python3-genpy`` and the definitions of the standard messages
(``ros-std-msgs``, ``ros-geometry-msgs``), or any ROS 1 installation::

    python3 bridge/ros/genmsgs.py OUT_DIR      # writes OUT_DIR/intera_core_msgs/...

then put ``OUT_DIR`` on ``PYTHONPATH``. Standalone (standard library, genpy, genmsg).
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile

import genpy.generate_initpy
import genpy.generator

PACKAGE = "intera_core_msgs"
HERE = os.path.dirname(os.path.abspath(__file__))
MSG_DIR = os.path.join(HERE, PACKAGE, "msg")
#: Where Debian (and ROS installations) keep the standard message definitions.
SHARE_DIRS = ("/usr/share", "/opt/ros/noetic/share")
DEPENDENCIES = ("std_msgs", "geometry_msgs")


def search_path() -> dict[str, list[str]]:
    """The message folder of this package and of its dependencies."""
    paths = {PACKAGE: [MSG_DIR]}
    for dep in DEPENDENCIES:
        found = [os.path.join(d, dep, "msg") for d in SHARE_DIRS]
        found = [d for d in found if os.path.isdir(d)]
        if not found:
            raise SystemExit(
                f"genmsgs.py: no {dep} message definitions in {' or '.join(SHARE_DIRS)} "
                f"(Debian: apt-get install ros-{dep.replace('_', '-')})"
            )
        paths[dep] = found[:1]
    return paths


def generate(out_dir: str) -> str:
    """Write ``out_dir/intera_core_msgs`` (replacing it whole); returns its path."""
    files = sorted(
        os.path.join(MSG_DIR, name) for name in os.listdir(MSG_DIR) if name.endswith(".msg")
    )
    os.makedirs(out_dir, exist_ok=True)
    target = os.path.join(out_dir, PACKAGE)
    work = tempfile.mkdtemp(prefix=".genmsgs-", dir=out_dir)
    try:
        msg_out = os.path.join(work, PACKAGE, "msg")
        code = genpy.generator.MsgGenerator().generate_messages(
            PACKAGE, files, msg_out, search_path()
        )
        if code:
            raise SystemExit(f"genmsgs.py: genpy failed ({code})")
        genpy.generate_initpy.write_modules(msg_out)
        with open(os.path.join(work, PACKAGE, "__init__.py"), "w") as f:
            f.write("")
        old = target + ".old"
        if os.path.exists(target):
            os.replace(target, old)
        os.replace(os.path.join(work, PACKAGE), target)
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return target


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: genmsgs.py OUT_DIR", file=sys.stderr)
        return 2
    print(generate(argv[0]))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
