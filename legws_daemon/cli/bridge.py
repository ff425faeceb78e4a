"""``legws bridge``: tools of the robot-side bridge; ``legws bridge fake`` runs a fake one.

The real bridge runs on the robot's PC (``bridge/intera_bridge.py``). The fake one plays
its part in this process (:class:`~legws_daemon.hardware.fake_bridge.FakeBridge`), so the
``sawyer`` profile can be tried without a robot. The profile's transport normally has the
daemon listen on a loopback endpoint; the fake bridge connects to it (its listen endpoints
become connect endpoints) unless ``--listen``/``--connect``/``--zenoh-config`` say otherwise.
"""

from __future__ import annotations

import signal
import threading
from pathlib import Path
from types import FrameType

import click

from legws_daemon.cli.numbers import FiniteFloat
from legws_daemon.errors import InputError
from legws_daemon.formats.printable import echo
from legws_daemon.formats.profile import (
    COMMAND_BURST,
    ProfileSpec,
    TransportSpec,
    endpoint_problem,
    load_profile_named,
)
from legws_daemon.scene.catalog import load_scene


def limits_line(profile: ProfileSpec) -> str:
    """The limits a bridge on ``profile`` enforces, in one line."""
    b, ws = profile.bridge, profile.workspace
    box = " ".join(
        f"{axis} [{lo:g}, {hi:g}]" for axis, (lo, hi) in zip("xyz", (ws.x, ws.y, ws.z), strict=True)
    )
    return (
        f"limits: joint speed <= {b.joint_speed_cap:g} rad/s, EE speed <= {b.ee_speed_cap:g} "
        f"m/s, EE in {box} m + {b.workspace_margin:g} m, ttl <= {b.max_ttl:g} s, "
        f"<= {b.command_rate_hz:g} commands/s (burst {COMMAND_BURST})"
    )


def bridge_transport(
    profile: ProfileSpec, listen: tuple[str, ...], connect: tuple[str, ...]
) -> TransportSpec:
    """The fake bridge's transport: the profile's, turned round, or the given endpoints.

    Without endpoints, the profile's listen endpoints (where the daemon listens) become
    connect endpoints; with ``listen`` and/or ``connect``, exactly those are used.
    """
    for flag, endpoints in (("--listen", listen), ("--connect", connect)):
        for endpoint in endpoints:
            problem = endpoint_problem(endpoint)
            if problem is not None:
                raise InputError(problem, field=flag)
    spec = profile.transport
    if listen or connect:
        return spec.model_copy(update={"listen": list(listen), "connect": list(connect)})
    return spec.model_copy(update={"listen": [], "connect": [*spec.listen, *spec.connect]})


@click.group("bridge")
def bridge_group() -> None:
    """The robot-side bridge (the real one is bridge/intera_bridge.py on the robot's PC)."""


@bridge_group.command("fake")
@click.option(
    "--profile",
    "profile_name",
    required=True,
    help="Hardware profile, by name (hw_profiles/NAME.toml, e.g. sawyer) or as a .toml path: "
    "robot name (zenoh keys), transport, and the limits the bridge enforces ([bridge], "
    "[workspace]).",
)
@click.option(
    "--scene",
    default="desk",
    show_default=True,
    help="Scene name or .toml path; the arm starts at its EE home pose.",
)
@click.option(
    "--zenoh-config",
    type=click.Path(path_type=Path),
    help="JSON5 zenoh configuration for a real network (replaces the profile's transport).",
)
@click.option(
    "--listen", multiple=True, metavar="ENDPOINT", help="Listen here instead (repeatable)."
)
@click.option(
    "--connect", multiple=True, metavar="ENDPOINT", help="Connect here instead (repeatable)."
)
@click.option(
    "--rate",
    type=FiniteFloat(1.0, 1000.0),
    default=200.0,
    show_default=True,
    help="Integration and state publication rate, Hz.",
)
def fake_cmd(
    profile_name: str,
    scene: str,
    zenoh_config: Path | None,
    listen: tuple[str, ...],
    connect: tuple[str, ...],
    rate: float,
) -> None:
    """Run a fake Sawyer bridge until SIGINT or SIGTERM.

    It publishes joint states on legws/<robot>/bridge/state and integrates the joint
    velocity commands from legws/<robot>/bridge/command within the profile's [bridge]
    limits and [workspace] box; any message on legws/<robot>/stop/* stops it until a
    resume on legws/<robot>/bridge/resume (docs/bridge.md).
    """
    profile = load_profile_named(profile_name)
    if zenoh_config is not None and (listen or connect):
        raise InputError("--zenoh-config replaces the transport: give no --listen/--connect")
    sc = load_scene(scene)

    # zenoh, mujoco and the fake load only here: other commands never pay for them
    from legws_daemon.transport.session import config_from_file, config_from_spec, open_session

    if zenoh_config is not None:
        config = config_from_file(zenoh_config)
        where = str(zenoh_config)
    else:
        transport = bridge_transport(profile, listen, connect)
        config = config_from_spec(transport)
        where = ", ".join(
            [f"listen {e}" for e in transport.listen] + [f"connect {e}" for e in transport.connect]
        )

    from legws_daemon.hardware.fake_bridge import FakeBridge
    from legws_daemon.transport.security import authentication_problem

    problem = authentication_problem(config)
    if problem is not None:  # a fake moves nothing: said, not refused (the real one refuses)
        echo(
            f"fake bridge: INSECURE TRANSPORT: {problem}; any process that reaches it can "
            "command this arm within its limits",
            err=True,
        )

    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with (
            open_session(config) as session,
            FakeBridge(
                session,
                profile.robot,
                sc,
                arm=profile.arm,
                rate_hz=rate,
                limits=profile.bridge,
                workspace=profile.workspace,
            ) as fake,
        ):
            echo(
                f"fake bridge for '{profile.robot}' at {rate:g} Hz on {fake.state_key} and "
                f"{fake.command_key} ({where or 'no endpoints'}); SIGINT or SIGTERM stops it"
            )
            echo(limits_line(profile))
            while not stop.wait(0.2):
                pass
            received, rejected, limited = fake.received, fake.rejected, fake.limited
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    enforced = ", ".join(f"{name} {n}" for name, n in limited.items() if n) or "none"
    echo(
        f"fake bridge stopped: {received} commands received, {rejected} rejected; "
        f"limits enforced: {enforced}"
    )


#: What a robot's PC needs beside a bridge script: the standard-library parts of legws it
#: imports (the one guard, the arm descriptions), in the checkout's layout.
BUNDLE_FILES = (
    "legws_daemon/__init__.py",
    "legws_daemon/safety/__init__.py",
    "legws_daemon/safety/limits.py",
)


#: The robot-side bridge of each arm that has one (``bridge/<script>``) and whether it needs
#: the arm's kinematic chain (the Intera bridge computes the endpoint itself; the Franka
#: bridge takes it from libfranka's model).
BRIDGES: dict[str, tuple[str, bool]] = {
    "sawyer": ("intera_bridge.py", True),
    "panda": ("franka_bridge.py", False),
}


def write_bundle(out: Path, arm_name: str = "sawyer") -> list[Path]:
    """Copy the arm's bridge script (:data:`BRIDGES`), the limit module and the arm tables
    into ``out`` (the checkout's layout: the bridge finds them in the folder above its
    own), and write the arm's chain from its model when its bridge needs it. The files
    written."""
    import shutil

    if arm_name not in BRIDGES:
        raise InputError(
            f"no robot-side bridge for arm {arm_name!r} (bridges: {', '.join(BRIDGES)}; "
            "the contract to write one: docs/bridge.md)",
            field="--arm",
        )
    script, chain = BRIDGES[arm_name]
    root = Path(__file__).parents[2]
    written = []
    arms = sorted((root / "legws_daemon" / "arms").glob("*.py"))
    for src in [root / "bridge" / script, *(root / f for f in BUNDLE_FILES), *arms]:
        dst = out / src.relative_to(root)
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, dst)
        written.append(dst)
    if chain:
        from legws_daemon.robot.chain_file import write_chain

        written.append(write_chain(arm_name, out / "bridge" / "chains"))
    return written


@bridge_group.command("bundle")
@click.option("--out", type=click.Path(path_type=Path), required=True, help="Folder to write.")
@click.option(
    "--arm",
    "arm_name",
    type=click.Choice(sorted(BRIDGES)),
    default="sawyer",
    show_default=True,
    help="The arm whose bridge to bundle (sawyer: intera_bridge.py, panda: franka_bridge.py).",
)
def bundle_cmd(out: Path, arm_name: str) -> None:
    """Write what the robot's PC needs to run the arm's bridge without legws installed: the
    script, the one limit module, the arm tables and (the Sawyer's) the arm's kinematic
    chain from its model. Copy the folder; run `python3 OUT/bridge/<script>`."""
    if out.exists() and any(out.iterdir()):
        raise InputError(f"{out} exists and is not empty", field="--out")
    files = write_bundle(out, arm_name)
    script = out / "bridge" / BRIDGES[arm_name][0]
    echo(f"bridge bundle: {len(files)} files in {out}; run python3 {script}")
