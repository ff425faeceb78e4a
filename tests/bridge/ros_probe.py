"""What the simulated Sawyer says on ROS, for test_ros_e2e.py: a rospy node (run in
``.venv-ros``) appending ``/robot/joint_states`` (every 5th: 20 Hz) and ``/robot/state`` (on
a change) to a JSONL file, each line with the monotonic time of its receipt.

    python ros_probe.py OUT.jsonl
"""

from __future__ import annotations

import json
import sys
import threading
import time
from typing import Any

import rospy
from intera_core_msgs.msg import RobotAssemblyState
from sensor_msgs.msg import JointState

JOINTS = [f"right_j{i}" for i in range(7)]


def main(path: str) -> int:
    out = open(path, "a", buffering=1)  # noqa: SIM115 (open for the node's life)
    lock = threading.Lock()
    count = [0]
    last: list[Any] = [None]

    def write(doc: dict[str, Any]) -> None:
        with lock:
            out.write(json.dumps({"t": time.monotonic(), **doc}) + "\n")

    def on_joints(msg: Any) -> None:
        count[0] += 1
        if count[0] % 5:
            return
        index = {name: i for i, name in enumerate(msg.name)}
        write(
            {
                "q": [msg.position[index[n]] for n in JOINTS],
                "dq": [msg.velocity[index[n]] for n in JOINTS],
            }
        )

    def on_state(msg: Any) -> None:
        state = {"enabled": msg.enabled, "stopped": msg.stopped, "source": msg.estop_source}
        if state != last[0]:
            last[0] = state
            write({"state": state})

    rospy.init_node("legws_test_probe")
    rospy.Subscriber("/robot/joint_states", JointState, on_joints, queue_size=10)
    rospy.Subscriber("/robot/state", RobotAssemblyState, on_state)
    rospy.spin()
    out.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
