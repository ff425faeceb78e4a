"""``legws assets``: the cached robot description (the Sawyer's MJCF and meshes)."""

from __future__ import annotations

import click

from legws_daemon.errors import InputError
from legws_daemon.sim import assets


@click.group("assets")
def assets_cmd() -> None:
    """The Sawyer model, fetched once with pip from robosuite's wheel and cached."""


@assets_cmd.command("fetch")
@click.option("--force", is_flag=True, help="Download again even when already cached.")
def fetch_cmd(force: bool) -> None:
    """Download the Sawyer model into the asset cache (once); print its folder."""
    if not force:
        try:
            click.echo(assets.sawyer_dir())
            return
        except InputError:
            pass
    click.echo(
        f"legws: downloading robosuite=={assets.ROBOSUITE_VERSION} with pip for its Sawyer model",
        err=True,
    )
    click.echo(assets.fetch(force=force))


@assets_cmd.command("status")
def status_cmd() -> None:
    """Print the Sawyer model's folder; exit 2 with one line when it is not fetched."""
    try:
        folder = assets.sawyer_dir()
    except InputError:
        raise InputError(
            f"the Sawyer model is not fetched (looked in {assets.assets_dir() / 'sawyer'}); "
            f"fetch it with: {assets.FETCH_COMMAND}"
        ) from None
    click.echo(folder)
