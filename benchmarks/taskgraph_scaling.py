"""Task-graph checks against the size of the graph: linear in stages and transitions.

Layered feeding graphs (pick a food, then k two-way choices — dip in chocolate or in
sprinkles, both leading to both stages of the next layer — then feed: 2k + 2 stages, 2^k
paths) and chains of optional dips (every stage a two-way choice: the next dip or the one
after; Fibonacci many paths), written as TOML files. Per graph, median of ``--repeats``
runs after a warm-up, in process:

- check: what ``legws taskgraph check FILE`` does (read, validate, check against the scene,
  the summary line with the path count);
- show: the text of ``legws taskgraph show FILE`` (the graph already loaded);
- png: the diagram of ``legws taskgraph show FILE --png`` (the graph already loaded);
- old: the check as it was before, listing every path (only while there are at most
  ``--old-max-paths``).

Layered graphs beyond the format's 64 stages (32 and 63 layers) are built in memory: their
rows time the held-object check and the path count only.

Usage:
    python benchmarks/taskgraph_scaling.py [--repeats 5] [--old-max-paths 70000]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from timing import median_seconds

from legws_daemon.cli.taskgraph import summary, tree
from legws_daemon.scene.catalog import load_scene
from legws_daemon.task.actions import action
from legws_daemon.task.diagram import diagram_png
from legws_daemon.task.graph import Stage, TaskGraph
from legws_daemon.task.taskgraph_file import held_problem, load_taskgraph

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.task.test_graph_scaling import all_paths  # the brute force of the tests


def _stage(name: str, candidates: list[str], act: str, nxt: list[str]) -> str:
    quoted = ", ".join(f'"{c}"' for c in candidates)
    text = f'[[stages]]\nname = "{name}"\ncandidates = [{quoted}]\naction = "{act}"\n'
    if nxt:
        text += "next = [" + ", ".join(f'"{n}"' for n in nxt) + "]\n"
    return text + "\n"


def layered(layers: int) -> list[tuple[str, list[str], str, list[str]]]:
    """(name, candidates, action, next) of the layered graph's stages."""

    def layer(i: int) -> list[str]:
        return [f"a{i}", f"b{i}"] if i <= layers else ["feed"]

    bowls = ["chocolate_bowl", "sprinkles_bowl"]
    out = [("food", ["strawberry", "grape", "brownie"], "pick", layer(1))]
    for i in range(1, layers + 1):
        out += [(s, [b], "dip", layer(i + 1)) for s, b in zip(layer(i), bowls, strict=True)]
    return [*out, ("feed", ["mouth"], "feed", [])]


def chain(dips: int) -> list[tuple[str, list[str], str, list[str]]]:
    """(name, candidates, action, next) of the chain of optional dips."""
    names = ["food", *(f"d{i}" for i in range(1, dips + 1)), "feed"]
    out = [("food", ["strawberry", "grape", "brownie"], "pick", names[1:3])]
    for i in range(1, dips + 1):
        bowl = "chocolate_bowl" if i % 2 else "sprinkles_bowl"
        out.append((names[i], [bowl], "dip", names[i + 1 : i + 3]))
    return [*out, ("feed", ["mouth"], "feed", [])]


def toml(name: str, stages: list[tuple[str, list[str], str, list[str]]]) -> str:
    text = f'schema_version = 1\nname = "{name}"\nscene = "feeding"\n\n'
    return text + "".join(_stage(*s) for s in stages)


def in_memory(stages: list[tuple[str, list[str], str, list[str]]]) -> TaskGraph:
    return TaskGraph(
        "big", "feeding",
        {n: Stage(n, tuple(c), a, tuple(x)) for n, c, a, x in stages},
    )  # fmt: skip


def old_check(graph: TaskGraph) -> None:
    """The held-object check and path count as they were: every path listed."""
    for path in all_paths(graph):
        held = False
        for name in path:
            act = action(graph.stages[name].action)
            if act.needs_held != held:
                raise AssertionError(name)
            held = held if act.holds_after is None else bool(act.holds_after)


def ms(seconds: float) -> str:
    return f"{seconds * 1e3:.2f}"


def row(name: str, graph: TaskGraph, *times: str) -> tuple[str, ...]:
    choices = sum(len(s.next) > 1 for s in graph.stages.values())
    transitions = sum(len(s.next) for s in graph.stages.values())
    shape = (str(choices), str(len(graph.stages)), str(transitions), str(graph.path_count()))
    return (name, *shape, *times)


HEADER = ("graph", "choice stages", "stages", "transitions", "paths", "check ms", "show ms",
          "png ms", "old check ms")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--old-max-paths", type=int, default=70_000)
    args = ap.parse_args()
    scene = load_scene("feeding")
    cases = [("layered", k, layered(k)) for k in (8, 16, 31)]
    cases += [("chain", k, chain(k)) for k in (8, 16, 32, 62)]
    rows: list[tuple[str, ...]] = []
    with tempfile.TemporaryDirectory() as folder:
        for shape, k, stages in cases:
            path = Path(folder) / f"{shape}{k}.toml"
            path.write_text(toml(path.stem, stages), encoding="utf-8")

            def check(path: Path = path) -> str:
                graph, _ = load_taskgraph(path, scene)
                return summary(path, graph)

            graph, _ = load_taskgraph(path, scene)
            check_s, _ = median_seconds(check, args.repeats)
            show_s, _ = median_seconds(lambda g=graph: tree(g), args.repeats)
            png_s, _ = median_seconds(lambda g=graph: diagram_png(g), args.repeats)
            old = "-"
            if graph.path_count() <= args.old_max_paths:
                old = ms(median_seconds(lambda g=graph: old_check(g), args.repeats)[0])
            rows.append(row(f"{shape} {k}", graph, ms(check_s), ms(show_s), ms(png_s), old))
            print(" | ".join(rows[-1]), flush=True)
    for k in (32, 63):  # beyond the format's 64 stages: the dynamic programmes alone
        graph = in_memory(layered(k))
        dp_s, _ = median_seconds(lambda g=graph: (held_problem(g), g.path_count()), args.repeats)
        rows.append(row(f"layered {k} (in memory)", graph, f"{ms(dp_s)} (DP)", "-", "-", "-"))
        print(" | ".join(rows[-1]), flush=True)
    print()
    print("| " + " | ".join(HEADER) + " |")
    print("|" + "---|" * len(HEADER))
    for r in rows:
        print("| " + " | ".join(r) + " |")


if __name__ == "__main__":
    main()
