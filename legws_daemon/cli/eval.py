"""``legws eval``: the paper's simulation protocol on random or given layouts."""

from __future__ import annotations

import json
import os
from pathlib import Path

import click

from legws_daemon.core.params import COST_FORMS, CostForm, Params
from legws_daemon.errors import InputError
from legws_daemon.scene.scene import Layout


def parse_layouts(specs: tuple[str, ...], scene_name: str) -> tuple[str, list[str]]:
    """``random:N`` or layout files; returns ``("random", [N])`` or ``("files", paths)``."""
    items = [part for spec in specs for part in spec.split(",") if part]
    if not items:
        raise InputError("expected random:N or layout files", field="--layouts")
    if items[0].startswith("random:"):
        if len(items) > 1:
            raise InputError("random:N cannot be mixed with files", field="--layouts")
        count = items[0].removeprefix("random:")
        if not count.isdigit() or not 1 <= int(count) <= 10_000:
            raise InputError(
                f"expected random:N with 1 <= N <= 10000, got {items[0]!r}", field="--layouts"
            )
        return "random", [count]
    return "files", items


@click.command("eval")
@click.option("--scene", "scene_name", required=True, help="Scene name or .toml path.")
@click.option(
    "--layouts",
    "layout_specs",
    multiple=True,
    default=("random:30",),
    show_default=True,
    help="random:N, or layout JSON files (repeat the option or separate with commas).",
)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--out", "out_dir", type=click.Path(path_type=Path, file_okay=False))
@click.option(
    "--workers", type=click.IntRange(1, 64), default=min(2, os.cpu_count() or 1), show_default=True
)
@click.option("--cost", type=click.Choice(COST_FORMS), default="dragan", show_default=True)
@click.option("--quiet", is_flag=True, help="No progress bar.")
def eval_cmd(
    scene_name: str,
    layout_specs: tuple[str, ...],
    seed: int,
    out_dir: Path | None,
    workers: int,
    cost: CostForm,
    quiet: bool,
) -> None:
    """Run the simulation protocol (method.md §8) and report accuracy, T_infer and rates.

    Writes DIR/eval.json and DIR/eval.md with --out; prints the Markdown table.
    """
    from tqdm import tqdm

    from legws_daemon.formats.files import write_atomic
    from legws_daemon.scene.catalog import load_scene
    from legws_daemon.scene.constraints import require_feasible
    from legws_daemon.scene.layout_file import load_layout
    from legws_daemon.sim.evaluate import markdown, random_layouts, run_eval

    scene = load_scene(scene_name)
    kind, items = parse_layouts(layout_specs, scene.name)
    layouts: list[Layout]
    if kind == "random":
        layouts = random_layouts(scene, int(items[0]), seed)
    else:
        layouts = [require_feasible(scene, load_layout(Path(i), scene), i) for i in items]
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
    with tqdm(total=len(layouts), desc=f"eval {scene.name}", unit="layout", disable=quiet) as bar:
        report = run_eval(
            scene, layouts, seed, params=Params(cost=cost), workers=workers, progress=bar.update
        )
    text = markdown(report)
    if out_dir is not None:
        write_atomic(
            out_dir / "eval.json", (json.dumps(report, indent=2, allow_nan=False) + "\n").encode()
        )
        write_atomic(out_dir / "eval.md", text.encode())
    click.echo(text)
