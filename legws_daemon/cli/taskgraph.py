"""``legws taskgraph check|show``: validate a task graph, print it as a tree or draw it."""

from __future__ import annotations

from decimal import Decimal
from pathlib import Path

import click

from legws_daemon.formats.files import output_folder, write_atomic
from legws_daemon.formats.printable import echo
from legws_daemon.task.decisions import decision_points
from legws_daemon.task.graph import Stage, TaskGraph
from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph


def _plural(n: int, word: str) -> str:
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


#: Path counts up to this are printed in full; larger ones as "about 2.1e9 paths".
EXACT_PATHS = 10**6


def count_paths_text(n: int) -> str:
    """``1 path``, ``524288 paths``; above :data:`EXACT_PATHS` ``about 2.1e9 paths`` (two
    significant digits: a 64-stage graph may have up to 2^62, about 4.6e18)."""
    if n <= EXACT_PATHS:
        return _plural(n, "path")
    mantissa, exponent = f"{Decimal(n):.1e}".split("e")  # exact for any int, no float
    return f"about {mantissa}e{int(exponent)} paths"


def summary(path: Path, graph: TaskGraph) -> str:
    """One line: stages, decision points (and how many infer), paths, scene, repeat.

    The paths are counted, not listed (:meth:`TaskGraph.path_count`)."""
    points = decision_points(graph)
    inferred = sum(p.inference for p in points)
    choices = sum(p.is_choice for p in points)
    repeat = ", repeats until consumed" if graph.repeat == "until_consumed" else ""
    return (
        f"{path}: ok: {_plural(len(graph.stages), 'stage')}, "
        f"{_plural(len(points), 'decision point')} ({inferred} with inference, "
        f"{_plural(choices, 'choice')}), {count_paths_text(graph.path_count())}, "
        f"scene {graph.scene}{repeat}"
    )


def _stage_line(stage: Stage, fixed: tuple[str, ...]) -> str:
    names = [f"{c} (fixed)" if c in fixed else c for c in stage.candidates]
    prompt = f' "{stage.prompt}"' if stage.prompt else ""
    single = "  [no inference]" if len(stage.candidates) == 1 else ""
    return f"{stage.name}: {stage.action} {{{', '.join(names)}}}{prompt}{single}"


def tree(graph: TaskGraph) -> list[str]:
    """The graph as an indented tree from the start; a stage met again is not expanded
    ("(shown above)"): a line per stage, transition and choice, however many paths."""
    fixed = ", ".join(graph.fixed) or "none"
    lines = [
        f"task graph '{graph.name}' ({graph.source}): scene {graph.scene}, repeat "
        f"{graph.repeat}, fixed objects: {fixed}",
    ]
    lines += [f"  {t}" for t in graph.description.strip().splitlines()]
    lines.append("")
    shown: set[str] = set()

    def walk(name: str, prefix: str, branch: str, rest: str) -> None:
        stage = graph.stages[name]
        if name in shown:
            lines.append(f"{prefix}{branch}{name} (shown above)")
            return
        shown.add(name)
        lines.append(f"{prefix}{branch}{_stage_line(stage, graph.fixed)}")
        inner = prefix + rest
        nxt = stage.next
        if len(nxt) > 1:
            union = sum(len(graph.stages[n].candidates) for n in nxt)
            lines.append(
                f"{inner}└─ choice: {' | '.join(nxt)} (the daemon infers over their {union} "
                "candidates; the commit picks the branch)"
            )
            inner += "   "
        elif not nxt and graph.repeat == "until_consumed":
            lines.append(f"{inner}└─ repeat from {graph.start} while it has candidates left")
        for i, n in enumerate(nxt):
            last = i == len(nxt) - 1
            walk(n, inner, "└─ " if last else "├─ ", "   " if last else "│  ")

    walk(graph.start, "", "", "")
    return lines


@click.group("taskgraph")
def taskgraph_group() -> None:
    """Task graphs (taskgraphs/*.toml): check one, or show it as a tree or a diagram."""


@taskgraph_group.command("check")
@click.argument("taskgraph")
def check_cmd(taskgraph: str) -> None:
    """Validate TASKGRAPH (a name in taskgraphs/ or a path) against its scene.

    Prints one summary line; a problem is one error line naming the file, the line and
    the field (exit 2).
    """
    path = resolve_taskgraph(taskgraph)
    graph, _ = load_taskgraph(path)
    echo(summary(path, graph))


@taskgraph_group.command("show")
@click.argument("taskgraph")
@click.option(
    "--png", "png", type=click.Path(path_type=Path, dir_okay=False), default=None,
    help="Also draw the graph as a diagram into this PNG file.",
)  # fmt: skip
def show_cmd(taskgraph: str, png: Path | None) -> None:
    """Print TASKGRAPH as a tree: each stage's action, candidates and prompt; choices,
    single-candidate stages (no inference) and repetition marked."""
    path = resolve_taskgraph(taskgraph)
    graph, _ = load_taskgraph(path)
    if png is not None:
        from legws_daemon.task.diagram import diagram_png

        output_folder(png.parent)
        write_atomic(png, diagram_png(graph))
    echo("\n".join(tree(graph)))
    if png is not None:
        echo(f"wrote {png}")
