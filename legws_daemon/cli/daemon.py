"""``legws daemon``: run the deployment daemon on a hardware profile."""

from __future__ import annotations

import functools
import ipaddress
import os
import signal
import threading
import time
from contextlib import ExitStack
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

import click

from legws_daemon.arms import DEFAULT_ARM
from legws_daemon.cli.numbers import FiniteFloat
from legws_daemon.cli.robot import robot_option
from legws_daemon.core.arbitration import POLICIES, AssistPolicy
from legws_daemon.core.params import COST_FORMS, CostForm, Params
from legws_daemon.errors import InputError
from legws_daemon.formats.files import open_output, output_path
from legws_daemon.formats.operator_file import OperatorFile, load_operator
from legws_daemon.formats.printable import echo
from legws_daemon.formats.profile import ProfileSpec, load_profile_named, with_arm
from legws_daemon.formats.validation import validate
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.constraints import require_feasible
from legws_daemon.scene.layout_file import load_layout
from legws_daemon.scene.scene import Scene
from legws_daemon.task.graph import TaskGraph
from legws_daemon.task.plan import Plan
from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph
from legws_daemon.transport.security import authentication_problem
from legws_daemon.transport.session import config_from_file, config_from_spec

if TYPE_CHECKING:
    from legws_daemon.telemetry.rerun_log import RerunLog

# rerun writes its own log lines (a viewer it cannot reach) from Rust straight to stderr,
# coloured with escape sequences even through a pipe: no colour (read when rerun is first
# imported, below); a NO_COLOR set by the user wins
os.environ.setdefault("NO_COLOR", "1")


def _load_plan(
    arg: str,
    graph: TaskGraph,
    scene: Scene,
    operator: OperatorFile | None = None,
    arm: str = DEFAULT_ARM,
) -> Plan:
    """``auto``: the cached plan of the graph (for ``operator`` when given), planned now if
    there is none or the cached one does not validate (a warning, then it is replaced) —
    before the control loop starts, with progress; else a folder (or its ``plan.json``)
    written by ``legws plan``, refused with one line naming the file, its line, the stage
    and the failed check unless every stage layout passes the checks of a ``--layout``
    file and records the certificates it gives (``check_plan``)."""
    if arg == "auto":
        from legws_daemon.design.stage_plan import cached_plan, plan_taskgraph

        people = (operator,) if operator is not None else ()
        try:
            plan = cached_plan(graph, scene, operators=people, arm=arm)
        except InputError as err:  # not usable: planned again and replaced
            echo(f"legws daemon: warning: {err}", err=True)
            plan = None
        if plan is not None:
            where = plan.directory
            echo(f"legws daemon: {graph.name} runs on its cached plan ({where}); "
                       "--plan none: the shipped layout", err=True)  # fmt: skip
            return plan
        who = f" for operator {operator.name}" if operator is not None else ""
        echo(
            f"legws daemon: no cached plan of {graph.name}{who}: planning it now, before the "
            f"control loop starts (`legws plan {graph.name}` makes it ahead; --plan none runs "
            "the shipped layout)",
            err=True,
        )
        started = time.monotonic()
        plan = plan_taskgraph(graph, scene, operators=people, arm=arm, progress=True)
        echo(f"legws daemon: planned {graph.name} in {time.monotonic() - started:.0f} s",
                   err=True)  # fmt: skip
        return plan
    from legws_daemon.task.plan_file import check_plan, load_plan_with_lines

    path = Path(arg)
    plan_json = path / "plan.json" if path.is_dir() else path
    plan, lines = load_plan_with_lines(plan_json, scene)
    if plan.taskgraph != graph.name:
        raise InputError(
            f"the plan is for task graph '{plan.taskgraph}', not '{graph.name}'", field="--plan"
        )
    planned_for = plan.settings.get("arm", DEFAULT_ARM)
    if planned_for != arm:  # its layouts were screened with another arm's reach
        raise InputError(
            f"the plan is for the arm '{planned_for}', not '{arm}' (plan it with "
            f"`legws plan {graph.name} --robot {arm}`)",
            field="--plan",
        )
    return check_plan(plan, graph, scene, str(plan_json), lines)


def cached_catalog_plan(graph: TaskGraph, scene: Scene, arm: str = DEFAULT_ARM) -> Plan:
    """``load_taskgraph`` with ``plan: "auto"``: the graph's cached plan (as ``--plan auto``
    would use), validated as ``--plan DIR`` is. Nothing is planned on the control loop:
    without one, or with one that does not validate, say how to make it."""
    from legws_daemon.design.stage_plan import cached_plan

    plan = cached_plan(graph, scene, arm=arm)
    if plan is None:
        robot = "" if arm == DEFAULT_ARM else f" --robot {arm}"
        raise InputError(
            f"no cached plan of task graph '{graph.name}'; make it with `legws plan "
            f"{graph.name}{robot}` (the daemon does not plan on its control loop)",
            field="plan",
        )
    return plan


def require_motion_allowed(spec: ProfileSpec, allow_motion: bool) -> None:
    """Refuse a profile that drives real hardware unless ``--allow-motion`` was given.

    Only the ``sim`` adapter is safe to start without asking: any other adapter commands a
    physical arm. A profile with ``link.fallback_to_sim`` needs the flag too, since the
    stand-in only takes over when the bridge is silent; a bridge that answers drives the arm.
    """
    if spec.adapter == "sim" or allow_motion:
        return
    raise click.UsageError(
        f"profile '{spec.name}' drives the real arm (adapter '{spec.adapter}'): the robot "
        "will move under joystick and autonomous commands; make sure the workspace is clear "
        "and the e-stop is in reach, then pass --allow-motion to start it"
    )


def require_secure_transport(
    spec: ProfileSpec, problem: str | None, insecure: bool, where: str
) -> bool:
    """Refuse a real arm on an unauthenticated transport unless ``--insecure-transport``;
    returns whether it runs insecure (said loudly in status, events and the log)."""
    if spec.adapter == "sim" or problem is None:
        return False
    if insecure:
        return True
    raise click.UsageError(
        f"profile '{spec.name}' drives the real arm but its transport ({where}) is not "
        f"authenticated: {problem}; run `legws secure init DIR` and pass --zenoh-config "
        "DIR/daemon.json5 (mutual TLS, passwords, access control), or --insecure-transport "
        "for a bench test nobody else can reach"
    )


def operator_for(spec: ProfileSpec, operator_file: Path | None) -> OperatorFile | None:
    """The operator file the certificates are for: ``--operator``, else the profile's
    ``control.operator`` (validated with the profile), else none (section 2's user)."""
    if operator_file is not None:
        return load_operator(operator_file)
    if spec.control.operator is not None:
        return load_operator(Path(spec.control.operator))
    return None


def install_stop_handlers(stop: threading.Event) -> None:
    """SIGINT and SIGTERM set ``stop`` (the loop ends within one period)."""

    def handler(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)


@click.command("daemon")
@click.option(
    "--profile",
    default="sim",
    show_default=True,
    help="Hardware profile: a name in hw_profiles/ or a .toml path.",
)
@click.option("--scene", help="Scene name or .toml path (default desk): pick one of its goals.")
@click.option(
    "--taskgraph",
    help="Task graph: a name in taskgraphs/ or a .toml path (its scene is used).",
)
@click.option(
    "--plan",
    "plan_arg",
    metavar="DIR|auto|none",
    help="Stage-specific layouts for --taskgraph: auto (the default without --layout: the "
    "cached plan, planned now if missing), a folder from `legws plan --out`, or none (the "
    "shipped layout, or --layout's).",
)
@click.option(
    "--layout",
    "layout_file",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Layout JSON of the scene (e.g. from legws optimize); default: the scene's.",
)
@click.option(
    "--rerun",
    "rerun_target",
    multiple=True,
    metavar="save:PATH|spawn|connect[:URL]|web[:[HOST:]PORT]",
    help="Stream to Rerun: a .rrd file, a spawned viewer, a running viewer, or the web "
    "viewer served on HOST:PORT (default 127.0.0.1:9090; the stream on PORT+1) for a "
    "browser. Repeat it for several (e.g. a file and the web viewer).",
)
@click.option(
    "--zenoh-config",
    type=click.Path(path_type=Path, dir_okay=False),
    help="zenoh JSON5 configuration for a real network (default: the profile's loopback).",
)
@click.option(
    "--rate",
    type=FiniteFloat(min=1.0, max=1000.0),
    help="Control rate, Hz (default: the profile's; the deadman stays the profile's).",
)
@click.option("--cost", type=click.Choice(COST_FORMS), help="Observer cost form (default dragan).")
@click.option(
    "--assist",
    type=click.Choice(POLICIES),
    help="Help before the commit (default: the profile's control.assist, commit): commit "
    "none; blend the operator's motion with the robot's toward the likely goal; hindsight "
    "the posterior-weighted assistance of hindsight optimisation (docs/daemon.md).",
)
@click.option(
    "--duration",
    type=FiniteFloat(min=0.0, min_open=True),
    help="Stop after this many seconds (default: run until SIGINT/SIGTERM).",
)
@click.option(
    "--trace",
    "trace_file",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Write one JSON line per tick: timing, the joystick sample used, when the command left.",
)
@click.option(
    "--operator",
    "operator_file",
    type=click.Path(path_type=Path, dir_okay=False),
    help="The operator file of the person at the joystick (legws operator calibrate or fit): "
    "every certificate is for their model, and the live watch re-fits it from the picks "
    "that complete (default: the profile's control.operator, else the paper's user).",
)
@robot_option(what="the profile's `arm` replaced (the stand-in's model, plans and limits)")
@click.option(
    "--allow-motion",
    is_flag=True,
    help="Required for a profile that drives real hardware (adapter other than sim, e.g. "
    "bridge or sawyer, even with fallback_to_sim): the arm will move.",
)
@click.option(
    "--insecure-transport",
    is_flag=True,
    help="Let a real arm's daemon run on a transport without authentication and access "
    "control (a bench test nobody else can reach); status and log say so.",
)
def daemon_cmd(
    profile: str,
    scene: str | None,
    taskgraph: str | None,
    plan_arg: str | None,
    layout_file: Path | None,
    rerun_target: tuple[str, ...],
    zenoh_config: Path | None,
    rate: float | None,
    cost: CostForm | None,
    assist: AssistPolicy | None,
    duration: float | None,
    trace_file: Path | None,
    operator_file: Path | None,
    robot: str | None,
    allow_motion: bool,
    insecure_transport: bool,
) -> int:
    """Run the shared-autonomy daemon: joystick over zenoh in, the robot out.

    Publishes status on legws/<robot>/status, events on legws/<robot>/events, answers
    commands on legws/<robot>/command. SIGINT/SIGTERM stop the robot and exit 0. A profile
    that drives real hardware (not the sim stand-in) starts only with --allow-motion.
    """
    from legws_daemon.daemon.service import DaemonConfig, DaemonService
    from legws_daemon.telemetry.terminal_log import log_to_terminal

    log_to_terminal("legws daemon")

    if scene is not None and taskgraph is not None:
        raise click.UsageError("give --scene or --taskgraph, not both")
    if plan_arg is not None and taskgraph is None:
        raise click.UsageError("--plan needs --taskgraph")
    if plan_arg is not None and plan_arg != "none" and layout_file is not None:
        raise click.UsageError("give --layout or --plan, not both (--plan none --layout FILE)")
    if trace_file is not None:
        output_path(trace_file)  # a device or folder there: one line before anything starts
    spec = load_profile_named(profile)
    if robot is not None:
        spec = with_arm(spec, robot)
    require_motion_allowed(spec, allow_motion)
    operator = operator_for(spec, operator_file)
    if assist is not None:
        spec = spec.model_copy(
            update={"control": spec.control.model_copy(update={"assist": assist})}
        )
    if rate is not None:
        control = spec.control.model_copy(update={"rate_hz": rate})
        spec = validate(
            ProfileSpec, {**spec.model_dump(), "control": control.model_dump()}, "--rate"
        )
    graph = plan = None
    if taskgraph is not None:
        graph, sc = load_taskgraph(resolve_taskgraph(taskgraph))
        # hands-off by default: a task graph runs on its plan unless told otherwise
        wanted = plan_arg if plan_arg is not None else "none" if layout_file else "auto"
        if wanted != "none":
            plan = _load_plan(wanted, graph, sc, operator, spec.arm)
    else:
        sc = load_scene(scene or "desk")
    layout = load_layout(layout_file, sc) if layout_file else sc.default_layout()
    require_feasible(sc, layout, str(layout_file) if layout_file else sc.source)
    params = Params(v_max=spec.control.v_max, dt=1.0 / spec.control.rate_hz)
    if cost is not None:
        params = params.with_cost(cost)
    if operator is not None:
        echo(f"legws daemon: certificates for operator {operator.name}: "
                   f"{operator.certify_with.describe()}", err=True)  # fmt: skip
    zcfg = config_from_file(zenoh_config) if zenoh_config else config_from_spec(spec.transport)
    problem = authentication_problem(zcfg)
    where = str(zenoh_config) if zenoh_config else "the profile's [transport]"
    # said in the log and as an event when the daemon starts, and in every status
    insecure = require_secure_transport(spec, problem, insecure_transport, where)
    stop = threading.Event()
    install_stop_handlers(stop)
    with ExitStack() as stack:
        telemetry: RerunLog | None = None
        if rerun_target:
            from legws_daemon.telemetry.rerun_log import RerunLog

            period = 1.0 / spec.control.rate_hz
            rerun_log = RerunLog(rerun_target, robot=spec.robot, tick_period=period)
            stack.callback(rerun_log.close)
            if rerun_log.web is not None:
                target = rerun_log.web.target
                echo(f"legws daemon: watch in a browser: {target.page_url}", err=True)
                if not ipaddress.IPv4Address(target.host).is_loopback:
                    echo(f"legws daemon: warning: the session is served unauthenticated "
                               f"to every host that reaches {target.host}", err=True)  # fmt: skip
            telemetry = rerun_log
        trace = stack.enter_context(open_output(trace_file)) if trace_file else None
        config = DaemonConfig(
            spec,
            sc,
            layout,
            params,
            zcfg,
            telemetry=telemetry,
            duration=duration,
            trace=trace,
            graph=graph,
            plan=plan,
            plan_loader=functools.partial(cached_catalog_plan, arm=spec.arm),
            transport_problem=problem,
            insecure_transport=insecure,
            operator=operator,
        )
        return DaemonService(config).run(stop)
