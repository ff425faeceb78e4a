"""``legws assets``: the cached robot description (the Sawyer's MJCF and meshes)."""

from __future__ import annotations

import click

from legws_daemon.errors import InputError
from legws_daemon.formats.printable import echo
from legws_daemon.robot import assets


@click.group("assets")
def assets_cmd() -> None:
    """The Sawyer model, fetched once with pip from robosuite's wheel and cached."""


@assets_cmd.command("fetch")
@click.option(
    "--force",
    is_flag=True,
    help="Download again and replace the cached folder (atomically), even when it is intact.",
)
def fetch_cmd(force: bool) -> None:
    """Download the Sawyer model into the asset cache (once); print its folder.

    A cached model that fails its integrity check is downloaded again too.
    """
    if not force:
        try:
            echo(assets.sawyer_dir())
            return
        except InputError:
            pass
    echo(
        f"legws: downloading robosuite=={assets.ROBOSUITE_VERSION} with pip for its Sawyer model",
        err=True,
    )
    echo(assets.fetch(force=True))


@assets_cmd.command("reachability")
@click.option(
    "--scene",
    "scene_name",
    default="desk",
    show_default=True,
    help="Any scene on the shared table (the map depends on table and home only).",
)
@click.option(
    "--build",
    "build_anew",
    is_flag=True,
    help="Build it even when cached or shipped with legws (to refresh the shipped map).",
)
def reachability_cmd(scene_name: str, build_anew: bool) -> None:
    """Cache the reachability map the optimiser screens grasps with: the one legws ships
    for this robot model, or built once (~1.5 min) when none matches."""
    from legws_daemon.robot.kinematics import home_configuration
    from legws_daemon.robot.reachability import SHIPPED, cache_key, load_or_build
    from legws_daemon.robot.world import World
    from legws_daemon.scene.catalog import load_scene

    scene = load_scene(scene_name)
    world = World(scene)
    q_home = home_configuration(world, scene.home.position, scene.home.rotation).q
    key = cache_key(world, q_home)
    path = assets.assets_dir() / "reachability" / f"{key}.npz"
    if build_anew or not (path.is_file() or (SHIPPED / f"{key}.npz").is_file()):
        echo("legws: building the reachability map (once per robot model, ~1.5 min)", err=True)
    load_or_build(world, q_home, build_anew=build_anew)
    echo(path)


@assets_cmd.command("status")
def status_cmd() -> None:
    """Print the Sawyer model's folder; exit 2 with one line when it is not fetched or
    fails its integrity check (the line names the file and the command that restores it)."""
    echo(assets.sawyer_dir())


@assets_cmd.command("check")
def check_cmd() -> None:
    """Check every file of the Sawyer model against the manifest its fetch wrote.

    Prints one line and exits 0 when intact; exits 2 with one line naming the damaged file
    and the command that restores it (``legws assets fetch --force``) otherwise.
    """
    v = assets.verify()
    echo(f"{v.folder}: intact ({v.files} files, {v.size} bytes, sha256 {v.digest})")
