"""``legws assets``: the cached robot descriptions (each registered arm's MJCF and meshes)."""

from __future__ import annotations

import click

from legws_daemon.arms import arm_names
from legws_daemon.errors import InputError
from legws_daemon.formats.printable import echo
from legws_daemon.robot import assets

_ROBOT = click.option(
    "--robot",
    "robot",
    type=click.Choice(arm_names()),
    default=None,
    help="One arm (default: every registered arm).",
)


@click.group("assets")
def assets_cmd() -> None:
    """The arms' models, fetched once with pip from robosuite's wheel and cached."""


@assets_cmd.command("fetch")
@click.option(
    "--force",
    is_flag=True,
    help="Download again and replace the cached folder (atomically), even when it is intact.",
)
@_ROBOT
def fetch_cmd(force: bool, robot: str | None) -> None:
    """Download the arms' models into the asset cache (once); print their folders.

    A cached model that fails its integrity check is downloaded again too (with
    ``--force`` every one is).
    """
    names = (robot,) if robot else arm_names()
    missing = []
    for name in names:
        try:
            assets.arm_dir(None, name)
        except InputError:
            missing.append(name)
    if force or missing:
        echo(
            f"legws: downloading robosuite=={assets.ROBOSUITE_VERSION} with pip for the "
            f"models of: {', '.join(names if force else missing)}",
            err=True,
        )
    for folder in assets.fetch(force=force, names=names).values():
        echo(folder)


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
@click.option(
    "--robot",
    "robots",
    type=click.Choice(arm_names()),
    multiple=True,
    help="The arm whose map to cache (repeat it for several; default: every arm).",
)
def reachability_cmd(scene_name: str, build_anew: bool, robots: tuple[str, ...]) -> None:
    """Cache the reachability maps the optimiser screens grasps with: for each arm the one
    legws ships for its model, or built once (~1.5 min) when none matches; prints each
    map's path."""
    from legws_daemon.robot.kinematics import home_configuration
    from legws_daemon.robot.reachability import SHIPPED, cache_key, load_or_build
    from legws_daemon.robot.world import World
    from legws_daemon.scene.catalog import load_scene

    scene = load_scene(scene_name)
    for robot in robots or arm_names():
        world = World(scene, arm=robot)
        q_home = home_configuration(world, scene.home.position, scene.home.rotation).q
        key = cache_key(world, q_home)
        path = assets.assets_dir() / "reachability" / f"{key}.npz"
        if build_anew or not (path.is_file() or (SHIPPED / f"{key}.npz").is_file()):
            echo(f"legws: building the reachability map of the {world.spec.title} (once per "
                 "robot model, ~1.5 min)", err=True)  # fmt: skip
        load_or_build(world, q_home, build_anew=build_anew)
        echo(path)


@assets_cmd.command("kernels")
@click.option("--quiet", is_flag=True, help="No line per part.")
def kernels_cmd(quiet: bool) -> None:
    """Compile the optimiser's numba kernels into numba's cache (``$NUMBA_CACHE_DIR``) once,
    on a tiny problem of every objective (~45 s here; set-up runs it beside its other
    steps): the first ``legws optimize`` and every process after it load them instead."""
    from legws_daemon.design.warmup import compile_kernels

    for part, seconds in compile_kernels().items():
        if not quiet:
            echo(f"{part}: {seconds:.1f} s")


@assets_cmd.command("status")
@_ROBOT
def status_cmd(robot: str | None) -> None:
    """Print the arms' model folders; exit 2 with one line when one is not fetched or
    fails its integrity check (the line names the file and the command that restores it)."""
    folders = [assets.arm_dir(None, name) for name in ((robot,) if robot else arm_names())]
    for folder in folders:  # all checked first: a damaged one is the only line
        echo(folder)


@assets_cmd.command("check")
@_ROBOT
def check_cmd(robot: str | None) -> None:
    """Check every file of the arms' models against the manifests their fetch wrote.

    Prints one line per arm and exits 0 when intact; exits 2 with one line naming the
    damaged file and the command that restores it (``legws assets fetch --force``)
    otherwise.
    """
    found = [assets.verify(None, name) for name in ((robot,) if robot else arm_names())]
    for v in found:  # all checked first: a damaged one is the only line
        echo(f"{v.folder}: intact ({v.files} files, {v.size} bytes, sha256 {v.digest})")
