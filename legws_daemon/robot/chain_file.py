"""An arm's forward kinematics as a chain file for the bridges (``bridge/chains/<arm>.json``):
the fixed transforms and revolute joints of its model from the base frame to the daemon's EE
point, read by :class:`~legws_daemon.safety.limits.Chain` on a robot PC without MuJoCo."""

from __future__ import annotations

import json
import math
from pathlib import Path

import mujoco

from legws_daemon.errors import InputError
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene


def chain_links(arm_name: str = "sawyer") -> list[dict[str, object]]:
    """The forward kinematics of ``arm_name``'s model as :class:`~legws_daemon.safety.limits.Chain`
    links: base frame (the mount undone) to the ``ee`` site, the daemon's EE point. For a
    bridge without MuJoCo (:data:`CHAIN_DIR`); the tests check it against the model."""
    world = World(load_scene("desk"), visual=False, arm=arm_name)
    m = world.model
    site = world.arm.ee_site
    links: list[dict[str, object]] = [
        {"pos": m.site_pos[site].tolist(), "quat": m.site_quat[site].tolist()}
    ]
    body = int(m.site_bodyid[site])
    while body != 0:
        link: dict[str, object] = {
            "pos": m.body_pos[body].tolist(),
            "quat": m.body_quat[body].tolist(),
        }
        if int(m.body_jntnum[body]):
            j = int(m.body_jntadr[body])
            if int(m.body_jntnum[body]) != 1 or m.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE:
                raise InputError(f"{arm_name}: a body with other than one hinge joint")
            link["axis"] = m.jnt_axis[j].tolist()
            link["anchor"] = m.jnt_pos[j].tolist()
            link["joint"] = m.joint(j).name.removeprefix(world.prefix)
        links.append(link)
        body = int(m.body_parentid[body])
    mount = world.spec.mount  # the base frame: the mount's yaw and position undone
    c, s = math.cos(mount.yaw), math.sin(mount.yaw)
    undo = [-(c * mount.x + s * mount.y), -(-s * mount.x + c * mount.y), -mount.z]
    w, _, _, z = mount.quaternion()
    links.append({"pos": undo, "quat": [w, 0.0, 0.0, -z]})
    links.reverse()
    return links


#: Where the bridges find each arm's chain (``<arm>.json``), beside ``bridge/intera_bridge.py``.
CHAIN_DIR = Path(__file__).parents[2] / "bridge" / "chains"


def write_chain(arm_name: str = "sawyer", folder: Path = CHAIN_DIR) -> Path:
    """Write ``<folder>/<arm>.json`` (default ``bridge/chains``) from the arm's model."""
    path = folder / f"{arm_name}.json"
    path.parent.mkdir(exist_ok=True)
    rows = [json.dumps(_no_negative_zero(link)) for link in chain_links(arm_name)]
    text = f'{{"arm": {json.dumps(arm_name)}, "links": [\n  ' + ",\n  ".join(rows) + "\n]}\n"
    path.write_text(text, encoding="utf-8")
    return path


def _no_negative_zero(link: dict[str, object]) -> dict[str, object]:
    return {k: [x + 0.0 for x in v] if isinstance(v, list) else v for k, v in link.items()}
