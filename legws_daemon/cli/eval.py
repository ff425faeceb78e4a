"""``legws eval``: the paper's simulation protocol on random, given or optimised layouts."""

from __future__ import annotations

import json
import os
from pathlib import Path

import click

from legws_daemon.cli.robot import robot_option
from legws_daemon.core.arbitration import POLICIES, AssistPolicy
from legws_daemon.core.params import COST_FORMS, CostForm, Params
from legws_daemon.errors import InputError
from legws_daemon.formats.printable import echo
from legws_daemon.scene.scene import Layout


def parse_layouts(specs: tuple[str, ...], scene_name: str) -> tuple[str, list[str]]:
    """``random:N``, layout files, or optimisation run folders; returns ``("random", [N])``,
    ``("files", paths)`` or ``("runs", folders)`` (every item a directory: folders and
    files do not mix)."""
    items = [part for spec in specs for part in spec.split(",") if part]
    if not items:
        raise InputError("expected random:N, layout files or run folders", field="--layouts")
    if items[0].startswith("random:"):
        if len(items) > 1:
            raise InputError("random:N cannot be mixed with files", field="--layouts")
        count = items[0].removeprefix("random:")
        if not count.isdigit() or not 1 <= int(count) <= 10_000:
            raise InputError(
                f"expected random:N with 1 <= N <= 10000, got {items[0]!r}", field="--layouts"
            )
        return "random", [count]
    folders = [Path(i).is_dir() for i in items]
    if all(folders):
        return "runs", items
    if any(folders):
        raise InputError(
            "run folders and layout files cannot be mixed, got the folder "
            f"{items[folders.index(True)]!r}",
            field="--layouts",
        )
    return "files", items


@click.command("eval")
@click.option("--scene", "scene_name", required=True, help="Scene name or .toml path.")
@click.option(
    "--layouts",
    "layout_specs",
    multiple=True,
    default=("random:30",),
    show_default=True,
    help="random:N, layout JSON files, or `legws optimize` run folders (their verified "
    "elites, see --top-k); repeat the option or separate with commas.",
)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--out", "out_dir", type=click.Path(path_type=Path, file_okay=False))
@click.option(
    "--workers", type=click.IntRange(1, 64), default=min(2, os.cpu_count() or 1), show_default=True
)
@click.option("--cost", type=click.Choice(COST_FORMS), default="dragan", show_default=True)
@click.option(
    "--episodes-per-goal",
    type=click.IntRange(1, 10_000),
    default=None,
    help="N picks per candidate goal per layout (each from home, objects reset) instead of "
    "the paper's pick orders (all permutations, 120 sampled for M >= 5).",
)
@click.option(
    "--top-k",
    "top_k",
    type=click.IntRange(min=1),
    default=None,
    help="With run folders in --layouts: evaluate each run's K best verified elites "
    "(RUN/elites.json; K = 1 also reads best_layout.json). Default 1.",
)
@click.option(
    "--operator",
    "operator_file",
    type=click.Path(path_type=Path, dir_okay=False),
    help="The simulated user steers like this person: an operator file's fitted model "
    "(method.md §10: speed, noise and its correlation, bias, steering), with the robot's clip.",
)
@click.option(
    "--assist",
    type=click.Choice(POLICIES),
    default="commit",
    show_default=True,
    help="Help before the commit: commit (none), blend (the robot's motion toward the "
    "likely goal blended in) or hindsight (hindsight optimisation's assistance).",
)
@robot_option("sawyer", what="the stand-in's arm the picks run on")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="Print the report as JSON (eval.json's content) instead of the Markdown tables.",
)
def eval_cmd(
    scene_name: str,
    layout_specs: tuple[str, ...],
    seed: int,
    out_dir: Path | None,
    workers: int,
    cost: CostForm,
    episodes_per_goal: int | None,
    top_k: int | None,
    operator_file: Path | None,
    assist: AssistPolicy,
    robot: str,
    quiet: bool,
    as_json: bool,
) -> None:
    """Run the simulation protocol (method.md §8) and report accuracy, T_infer and rates,
    and the person's metrics (method.md §9) with 95 % bootstrap intervals over layouts
    (and over runs when several run folders are given); a rate where every pick succeeded
    (or none did) gets its one-sided Clopper-Pearson bound instead.

    Writes DIR/eval.json and DIR/eval.md with --out; prints the Markdown tables.
    """
    from tqdm import tqdm

    from legws_daemon.formats.files import output_folder, write_atomic
    from legws_daemon.formats.operator_file import load_operator
    from legws_daemon.scene.catalog import load_scene
    from legws_daemon.scene.constraints import require_feasible
    from legws_daemon.scene.layout_file import load_layout
    from legws_daemon.sim.evaluate import Elite, load_elites, markdown, random_layouts, run_eval

    operator = load_operator(operator_file).fitted if operator_file is not None else None
    scene = load_scene(scene_name)
    kind, items = parse_layouts(layout_specs, scene.name)
    if top_k is not None and kind != "runs":
        raise InputError("needs optimisation run folders in --layouts", field="--top-k")
    layouts: list[Layout]
    elites: list[Elite] | None = None
    if kind == "random":
        layouts = random_layouts(scene, int(items[0]), seed)
    elif kind == "files":
        layouts = [require_feasible(scene, load_layout(Path(i), scene), i) for i in items]
    else:
        loaded = [pair for i in items for pair in load_elites(Path(i), scene, top_k or 1)]
        layouts = [layout for layout, _ in loaded]
        elites = [elite for _, elite in loaded]
    if out_dir is not None:
        output_folder(out_dir)  # a file in the way is one line before any work
    with tqdm(total=len(layouts), desc=f"eval {scene.name}", unit="layout", disable=quiet) as bar:
        report = run_eval(
            scene, layouts, seed, params=Params(cost=cost), workers=workers, progress=bar.update,
            episodes_per_goal=episodes_per_goal, elites=elites, operator=operator, arm=robot,
            assist=assist,
        )  # fmt: skip
    text = markdown(report)
    data = json.dumps(report, indent=2, allow_nan=False) + "\n"
    if out_dir is not None:
        write_atomic(out_dir / "eval.json", data.encode())
        write_atomic(out_dir / "eval.md", text.encode())
    if as_json:
        click.echo(data, nl=False)  # machine-readable: JSON, not the printable text
    else:
        echo(text)
