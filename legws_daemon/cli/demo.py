"""``legws demo tea|lego|feeding``: the daemon and a simulated user through a whole task."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from legws_daemon.arms import arm
from legws_daemon.cli.numbers import FiniteFloat
from legws_daemon.cli.robot import robot_option
from legws_daemon.errors import InputError
from legws_daemon.formats.printable import echo
from legws_daemon.formats.profile import load_profile_named, with_arm
from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph


@click.command("demo")
@click.argument("taskgraph")
@click.option(
    "--out",
    type=click.Path(path_type=Path, file_okay=False),
    help="Folder for the recording and the summary (default: out/demo-<taskgraph>).",
)
@click.option(
    "--seed", type=int, default=0, show_default=True, help="The user's choices and noise."
)
@click.option(
    "--timeout",
    type=FiniteFloat(min=1.0),
    default=600.0,
    show_default=True,
    help="Stop the run after this many seconds.",
)
@click.option("--profile", default="sim", show_default=True, help="Hardware profile (a sim one).")
@click.option(
    "--plan/--no-plan",
    default=True,
    show_default=True,
    help="Stage-specific layouts from `legws plan` (cached after the first run), or the "
    "scene's default layout throughout.",
)
@robot_option(what="the stand-in's arm (its model, reach, plans and limits)")
@click.option(
    "--rerun",
    "web",
    metavar="web[:[HOST:]PORT]",
    help="Also serve the session to a browser: the Rerun web viewer on HOST:PORT (default "
    "127.0.0.1:9090; the stream on PORT+1); the URL is printed.",
)
def demo_cmd(
    taskgraph: str,
    out: Path | None,
    seed: int,
    timeout: float,
    profile: str,
    plan: bool,
    robot: str | None,
    web: str | None,
) -> None:
    """Run TASKGRAPH (tea, lego, feeding or a file) on the stand-in with a simulated user.

    Starts `legws daemon` on a private loopback port with a Rerun recording, steers like
    the paper's noisy user choosing a goal at random (seeded) at every decision, and
    writes recording.rrd, summary.json and summary.md: per decision, what the user went
    for, what the daemon committed to and when, and the certificate.
    """
    from legws_daemon.demo.run import markdown, run_demo
    from legws_daemon.formats.files import output_folder

    web_target = None
    if web is not None:
        from legws_daemon.telemetry.web_viewer import parse_web_target

        kind, sep, arg = web.partition(":")
        if kind != "web" or (sep and not arg):
            raise click.BadParameter(f"expected web or web:[HOST:]PORT, got {web!r}",
                                     param_hint="--rerun")  # fmt: skip
        web_target = parse_web_target(arg or None)
    spec = load_profile_named(profile)
    if spec.adapter != "sim":
        raise click.UsageError(f"the demo runs on a sim profile; '{profile}' is {spec.adapter}")
    if robot is not None:
        spec = with_arm(spec, robot)
    graph, scene = load_taskgraph(resolve_taskgraph(taskgraph))  # errors before starting
    folder = out if out is not None else Path("out") / f"demo-{graph.name}"
    output_folder(folder)  # a file or device in the way: one line before any planning
    plan_dir = None
    if plan:
        from legws_daemon.design.stage_plan import cached_plan, plan_taskgraph

        try:
            planned = cached_plan(graph, scene, arm=spec.arm)
        except InputError:  # damaged or stale: planned again below, and the cache replaced
            planned = None
        if planned is None:
            echo(f"legws: planning the layout of each decision of {graph.name} for the "
                 f"{arm(spec.arm).title}", err=True)  # fmt: skip
            planned = plan_taskgraph(graph, scene, arm=spec.arm, progress=False)
        else:
            echo(f"legws: the cached plan of {graph.name} for the {arm(spec.arm).title} "
                 f"({planned.directory})", err=True)  # fmt: skip
        plan_dir = planned.directory
        for d in planned.decisions:
            cert = "no inference" if d.certificate is None else f"J = {d.certificate:.3f}"
            echo(f"  {d.label}: {cert}", err=True)

    def show(event: dict[str, Any]) -> None:
        kind, d = event["kind"], event["detail"]
        if kind == "commit":
            how = "no inference" if d["single"] else f"p={d['p']} after {d['seconds']:.2f} s"
            echo(f"  {d.get('decision', d['stage'])}: commit {d['goal']} ({how})", err=True)
        elif kind in ("stage_done", "task_done", "fault", "warning", "cancel", "fallback"):
            detail = {k: v for k, v in d.items() if k not in ("posterior", "history")}
            echo(f"  {kind} {detail}", err=True)

    echo(f"legws: demo {graph.name} on the {arm(spec.arm).title} (seed {seed}) -> {folder}",
         err=True)  # fmt: skip
    if web_target is not None:
        echo(f"legws: watch in a browser: {web_target.page_url}", err=True)
    result = run_demo(graph.name if taskgraph == graph.name else taskgraph, spec, folder,
                      seed=seed, timeout=timeout, plan=plan_dir, log=show,
                      web=web)  # fmt: skip
    echo(markdown(result))
    if not result.completed:
        raise click.ClickException(f"the task did not complete; see {folder / 'daemon.log'}")
