"""``legws scenes``: the shipped scenes with their number of goals and objects."""

from __future__ import annotations

import json
from typing import Any

import click

from legws_daemon.formats.printable import echo
from legws_daemon.scene.catalog import load_scene, scene_names, scenes_dir


@click.command("scenes")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON list.")
def scenes_cmd(as_json: bool) -> None:
    """List the scenes: tier, M (candidate goals), total objects, the goals."""
    rows: list[dict[str, Any]] = []
    for name in scene_names():
        sc = load_scene(name)
        rows.append(
            {
                "name": sc.name,
                "tier": sc.spec.tier or "demo",
                "m": len(sc.goal_names),
                "total": len(sc.objects),
                "goals": list(sc.goal_names),
                "movable": list(sc.movable),
                "fixed": list(sc.fixed),
            }
        )
    if as_json:
        click.echo(json.dumps(rows))
        return
    echo(f"scenes in {scenes_dir()}")
    echo(f"{'name':<16}{'tier':<8}{'M':>3}{'total':>7}  goals")
    for r in rows:
        echo(f"{r['name']:<16}{r['tier']:<8}{r['m']:>3}{r['total']:>7}  {', '.join(r['goals'])}")
