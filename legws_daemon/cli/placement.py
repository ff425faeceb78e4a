"""``legws placement``: printable 1:1 placement mats of a plan's decisions or of one layout."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import click

from legws_daemon.errors import InputError
from legws_daemon.formats.printable import echo
from legws_daemon.scene.catalog import load_scene, scene_names
from legws_daemon.scene.scene import Scene
from legws_daemon.task.graph import TaskGraph
from legws_daemon.task.plan import Plan
from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph, taskgraphs_dir

if TYPE_CHECKING:  # drawing (matplotlib, OpenCV) loads only when the command runs
    from legws_daemon.placement.mat import Mat


def _is_path(source: str) -> bool:
    return source.endswith(".toml") or "/" in source or os.sep in source


def _graph(source: str) -> tuple[TaskGraph, Scene]:
    """The task graph ``source`` names (and its scene); a scene name says to pass --layout."""
    graph_file = taskgraphs_dir() / f"{source}.toml"
    if not _is_path(source) and not graph_file.is_file() and source in scene_names():
        raise InputError(
            f"'{source}' is a scene, not a task graph: pass --layout FILE (or --layout "
            "default, the scene file's layout) for a mat of one layout",
            field="TASKGRAPH",
        )
    return load_taskgraph(resolve_taskgraph(source))


def _scene(source: str) -> Scene:
    """The scene ``source`` names: a scene, or a task graph's scene."""
    if _is_path(source) or source in scene_names():
        return load_scene(source)
    if (taskgraphs_dir() / f"{source}.toml").is_file():
        return load_taskgraph(resolve_taskgraph(source))[1]
    return load_scene(source)  # the unknown-scene error, with the known ones


def _plan(graph: TaskGraph, scene: Scene, plan_arg: Path | None) -> Plan:
    """The plan of ``--plan DIR`` (checked against the graph as the daemon checks it), or
    the graph's cached plan (``legws plan GRAPH``); never planned here."""
    from legws_daemon.task.plan_file import check_plan, load_plan_with_lines

    if plan_arg is None:
        from legws_daemon.design.stage_plan import cached_plan  # the search stack: seconds

        plan = cached_plan(graph, scene)
        if plan is None:
            raise InputError(
                f"no cached plan of task graph '{graph.name}': make it with `legws plan "
                f"{graph.name}`, or pass --plan DIR (from `legws plan --out DIR`), or "
                "--layout FILE|default for one layout",
                field="plan",
            )
        return plan
    plan_json = plan_arg / "plan.json" if plan_arg.is_dir() else plan_arg
    plan, lines = load_plan_with_lines(plan_json, scene)
    return check_plan(plan, graph, scene, str(plan_json), lines)


def decision_stem(index: int, label: str) -> str:
    """The file name (without suffix) of decision ``label``: ``02-dip+feed``."""
    return f"{index:02d}-{label.replace('|', '+')}"


@click.command("placement")
@click.argument("source", metavar="TASKGRAPH|SCENE")
@click.option(
    "--layout",
    "layout_arg",
    metavar="FILE|default",
    help="One layout (a layout JSON, or `default`: the scene file's) instead of a plan; "
    "SOURCE is then a scene or a task graph (its scene).",
)
@click.option(
    "--plan",
    "plan_arg",
    type=click.Path(path_type=Path),
    help="A plan folder (or its plan.json) from `legws plan --out DIR` (default: the task "
    "graph's cached plan).",
)
@click.option(
    "--out",
    "out_dir",
    required=True,
    type=click.Path(path_type=Path),
    help="Folder for the PDFs and previews; created when missing.",
)
@click.option("--paper", type=click.Choice(["a4", "a3"]), default="a4", show_default=True)
def placement_cmd(
    source: str, layout_arg: str | None, plan_arg: Path | None, out_dir: Path, paper: str
) -> None:
    """Print placement mats: the table at true scale, tiled on A4 or A3 pages.

    Per decision of TASKGRAPH's plan (--plan DIR, or the cached plan of `legws plan
    TASKGRAPH`), or for one layout (--layout), writes NN-<decision>.pdf (only the pages
    that carry an object or a table marker, with registration marks, cut lines, page
    labels, where each page lies on the table and a 100 mm scale bar) and a PNG preview of
    the table with the printed pages, plus markers.pdf: each object's fiducial marker at
    true size, to stick on the objects. Print at 100 % (actual size), cut along the dashed
    lines, tape the pages that join so their registration crosses coincide, lay the rest
    by their printed distances from the table's edges, and put each object on its outline.
    The table's own markers are printed on the mat at their scene poses.
    """
    from legws_daemon.formats.files import output_folder, write_atomic
    from legws_daemon.placement.mat import decision_mat, layout_mat
    from legws_daemon.placement.pdf import markers_pdf, write_mat

    if layout_arg is not None and plan_arg is not None:
        raise click.UsageError("--layout and --plan exclude each other: one layout or a plan")
    mats: list[tuple[str, Mat]]
    if layout_arg is not None:
        from legws_daemon.scene.layout_file import load_layout

        scene = _scene(source)
        if layout_arg == "default":
            layout, title = scene.default_layout(), "the scene file's layout"
        else:
            layout, title = load_layout(Path(layout_arg), scene), f"layout {Path(layout_arg).name}"
        output_folder(out_dir)  # a file in the way: one line before the drawing
        mats = [("layout", layout_mat(scene, layout, title, paper))]
    else:
        graph, scene = _graph(source)
        plan = _plan(graph, scene, plan_arg)
        output_folder(out_dir)
        mats = [
            (decision_stem(i, d.label), decision_mat(scene, d, paper))
            for i, d in enumerate(plan.decisions, 1)
        ]
    for stem, mat in mats:
        pdf, png = write_mat(mat, out_dir, stem)
        echo(f"wrote {pdf} ({_pages(mat, paper)})")
        echo(f"wrote {png} (preview)")
        _warn_split(mat, pdf.name)
    markers = markers_pdf(scene, paper)
    if markers is not None:
        path = write_atomic(out_dir / "markers.pdf", markers)
        count = sum(o.marker is not None for o in scene.spec.objects)
        echo(f"wrote {path} ({count} object markers to cut out)")


def _pages(mat: Mat, paper: str) -> str:
    """``11 A4 pages, 9 portrait and 2 landscape, only where something lies; the whole
    table takes 21``."""
    t = mat.tiling
    count, (portrait, landscape) = len(t.pages), t.orientations
    if portrait and landscape:
        kinds = f"{portrait} portrait and {landscape} landscape"
    else:
        kinds = "portrait" if portrait else "landscape"
    out = f"{count} {paper.upper()} page{'s' if count != 1 else ''}, {kinds}"
    return f"{out}, only where something lies; the whole table takes {t.full}"


def _warn_split(mat: Mat, name: str) -> None:
    """One line on stderr per table marker that no tiling of the mat keeps on one page."""
    advice = "tape it flat and exact" + (
        ", or print on --paper a3" if mat.tiling.paper == "a4" else ""
    )
    for marker, pages in mat.split_markers():
        numbers = ", ".join(str(p.number) for p in pages)
        echo(
            f"legws: warning: table marker {marker.id} lies across the cut between "
            f"pages {numbers} of {name}: {advice}",
            err=True,
        )
