"""``legws optimize``: design a layout with quality-diversity search over the certificate."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from legws_daemon.cli.design_options import load_operators, objective_options, operator_options
from legws_daemon.cli.robot import robot_option
from legws_daemon.design import METHODS

if TYPE_CHECKING:
    from legws_daemon.formats.operator_file import OperatorFile

#: The progress bar's best score per objective: its name and the sign from the searched one.
SHOWN = {"slack": ("best_J", 1), "commit": ("best_K", -1), "rate": ("best_R", 1),
         "time": ("best_T", -1)}  # fmt: skip
#: What a run reports on stdout (one run, or each row of --all's index), from summary.json.
RESULT_KEYS = ("objective", "commit_objective", "commit_certified", "commit_rate_estimate",
               "commit_time_estimate", "coverage", "elites")  # fmt: skip


@click.command("optimize")
@click.option(
    "--scene", "scene_names", multiple=True,
    help="Scene name or .toml path; with --all, a list (repeat or comma-separate).",
)  # fmt: skip
@click.option("--all", "run_all_scenes", is_flag=True, help="Every scene (or the --scene list).")
@click.option("--seeds", help="With --all: comma-separated seeds (default: --seed).")
@click.option("--dask", "dask_address", help="With --all: Dask scheduler, tcp://HOST:PORT.")
@click.option("--workers", type=click.IntRange(1, 256), default=2, show_default=True,
              help="With --all: local worker processes (without --dask).")  # fmt: skip
@click.option("--method", type=click.Choice(METHODS), default="cma-me", show_default=True)
@objective_options("")
@operator_options("")
@click.option("--iterations", type=click.IntRange(1, 1_000_000), default=1000, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--movable", help="Comma-separated objects to place; all others stay fixed.")
@click.option(
    "--out", "out_dir", type=click.Path(path_type=Path, file_okay=False), default=None,
    help="Run folder (default: out/optimize/SCENE).",
)  # fmt: skip
@click.option("--no-cache", is_flag=True, help="Ignore and do not write the result cache.")
@robot_option("sawyer", what="the arm whose reach and grasps screen the layouts")
@click.option("--quiet", is_flag=True, help="No progress bar.")
def optimize_cmd(
    scene_names: tuple[str, ...],
    run_all_scenes: bool,
    seeds: str | None,
    dask_address: str | None,
    workers: int,
    method: str,
    objective_kind: str,
    commit_form: str,
    operator_file: Path | None,
    operator_files: str | None,
    iterations: int,
    seed: int,
    movable: str | None,
    out_dir: Path | None,
    no_cache: bool,
    robot: str,
    quiet: bool,
) -> None:
    """Optimise a scene's layout (method.md §5) and verify the best elite in simulation.

    Writes summary.json, best_layout.json, goals.json, elites.json, archive.csv,
    archive.png and best_layout.png to the run folder; `legws certify RUN/goals.json
    --commit` reproduces objective and commit_objective. With --all, runs scenes × seeds on
    a process pool or a Dask cluster. --operator FILE designs for one person (an operator
    file), --operators A,B for the worst of a group; summary.json then reports each
    person's certificates (operators) next to section 2's user's.
    """
    from tqdm import tqdm

    from legws_daemon.design.optimize import optimize
    from legws_daemon.formats.files import output_folder
    from legws_daemon.scene.catalog import load_scene
    from legws_daemon.scene.catalog import scene_names as all_names

    names_given = [n.strip() for spec in scene_names for n in spec.split(",") if n.strip()]
    people = load_operators(operator_file, operator_files)  # a bad file: one line, first
    if run_all_scenes:
        if robot != "sawyer":
            raise click.UsageError("--all runs on the Sawyer; give one --scene with --robot")
        _run_all(names_given or all_names(), seeds, seed, dask_address, workers, method,
                 objective_kind, commit_form, people, iterations, movable, out_dir,
                 quiet)  # fmt: skip
        return
    if seeds or dask_address:
        raise click.UsageError("--seeds and --dask go with --all")
    if len(names_given) != 1:
        raise click.UsageError("give one --scene (or --all)")
    scene = load_scene(names_given[0])
    names = [n.strip() for n in movable.split(",") if n.strip()] if movable else None
    if names is not None:
        scene.check_names(names, "--movable")
    out = output_folder(out_dir or Path("out") / "optimize" / scene.name)
    with tqdm(total=iterations, desc=f"{method} {scene.name}", unit="it", disable=quiet) as bar:

        def progress(it: int, best: float, coverage: float) -> None:
            bar.update(1)
            if it % 20 == 0 or it == iterations:
                name, sign = SHOWN[objective_kind]
                shown = {name: sign * best}
                bar.set_postfix(
                    {k: f"{v:.3f}" for k, v in shown.items()}, coverage=f"{coverage:.0%}"
                )

        summary = optimize(
            scene, out, method=method, iterations=iterations, seed=seed, movable=names,
            objective=objective_kind, commit_form=commit_form, operators=people, arm=robot,
            use_cache=not no_cache, progress=progress,
        )  # fmt: skip
    keys = (*RESULT_KEYS, "evaluations", "seconds", "cached")
    click.echo(json.dumps({k: summary[k] for k in keys} | {"out": str(out)}))


def _run_all(
    names: list[str],
    seeds: str | None,
    seed: int,
    dask_address: str | None,
    workers: int,
    method: str,
    objective_kind: str,
    commit_form: str,
    people: tuple[OperatorFile, ...],
    iterations: int,
    movable: str | None,
    out_dir: Path | None,
    quiet: bool,
) -> None:
    from tqdm import tqdm

    from legws_daemon.design.batch import Job, run_all
    from legws_daemon.errors import InputError
    from legws_daemon.formats.files import output_folder, write_atomic
    from legws_daemon.scene.catalog import load_scene

    try:
        seed_list = [int(s) for s in seeds.split(",")] if seeds else [seed]
    except ValueError:
        raise InputError(
            f"expected comma-separated integers, got {seeds!r}", field="--seeds"
        ) from None
    if movable:
        raise InputError("--movable names one scene's objects; not with --all", field="--movable")
    root = out_dir or Path("out") / "optimize"
    scenes = [load_scene(n) for n in names]  # validate every name before starting
    jobs = [
        Job(
            sc.source,
            s,
            str(root / sc.name / f"seed{s}"),
            method,
            iterations,
            None,
            objective_kind,
            commit_form,
            people,
        )
        for sc in scenes
        for s in seed_list
    ]
    output_folder(root)  # a file in the way is one line before any run starts
    bars: list[Any] = []

    def started() -> None:  # the bar appears once the pool or the cluster is there
        bars.append(tqdm(total=len(jobs), desc=f"{method} runs", unit="run", disable=quiet))

    try:
        results = run_all(
            jobs, dask=dask_address, workers=workers, progress=lambda _: bars[0].update(1),
            started=started,
        )  # fmt: skip
    finally:
        for bar in bars:
            bar.close()
    keys = ("scene", "seed", *RESULT_KEYS, "seconds", "cached", "out")
    table = [{k: r[k] for k in keys} for r in results]
    write_atomic(root / "index.json", (json.dumps(table, indent=2) + "\n").encode())
    click.echo(json.dumps(table))
