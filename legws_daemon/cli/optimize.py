"""``legws optimize``: design a layout with quality-diversity search over the certificate."""

from __future__ import annotations

import json
from pathlib import Path

import click

from legws_daemon.design.search import METHODS


@click.command("optimize")
@click.option("--scene", "scene_name", required=True, help="Scene name or .toml path.")
@click.option("--method", type=click.Choice(METHODS), default="cma-me", show_default=True)
@click.option("--iterations", type=click.IntRange(1, 1_000_000), default=1000, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--movable", help="Comma-separated objects to place; all others stay fixed.")
@click.option(
    "--out", "out_dir", type=click.Path(path_type=Path, file_okay=False), default=None,
    help="Run folder (default: out/optimize/SCENE).",
)  # fmt: skip
@click.option("--no-cache", is_flag=True, help="Ignore and do not write the result cache.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
def optimize_cmd(
    scene_name: str,
    method: str,
    iterations: int,
    seed: int,
    movable: str | None,
    out_dir: Path | None,
    no_cache: bool,
    quiet: bool,
) -> None:
    """Optimise a scene's layout (method.md §5) and verify the best elite in simulation.

    Writes summary.json, best_layout.json, goals.json, archive.csv, archive.png and
    best_layout.png to the run folder; `legws certify RUN/goals.json` reproduces the
    objective.
    """
    from tqdm import tqdm

    from legws_daemon.design.optimize import optimize
    from legws_daemon.scene.catalog import load_scene

    scene = load_scene(scene_name)
    names = [n.strip() for n in movable.split(",") if n.strip()] if movable else None
    if names is not None:
        scene.check_names(names, "--movable")
    out = out_dir or Path("out") / "optimize" / scene.name
    with tqdm(total=iterations, desc=f"{method} {scene.name}", unit="it", disable=quiet) as bar:

        def progress(it: int, best: float, coverage: float) -> None:
            bar.update(1)
            if it % 20 == 0 or it == iterations:
                bar.set_postfix(best_J=f"{best:.3f}", coverage=f"{coverage:.0%}")

        summary = optimize(
            scene, out, method=method, iterations=iterations, seed=seed, movable=names,
            use_cache=not no_cache, progress=progress,
        )  # fmt: skip
    keys = ("objective", "coverage", "elites", "evaluations", "seconds", "cached")
    click.echo(json.dumps({k: summary[k] for k in keys} | {"out": str(out)}))
