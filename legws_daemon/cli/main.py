"""Entry point of ``legws``: the command group and the error policy.

Bad input of any kind (a usage error, a file or field that does not validate, an
unknown name) prints one line ``legws: error: ...`` on stderr and exits 2. Nothing the
user can cause prints a traceback.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

import click

from legws_daemon import __version__
from legws_daemon.cli.assets import assets_cmd
from legws_daemon.cli.bridge import bridge_group
from legws_daemon.cli.certify import certify_cmd
from legws_daemon.cli.daemon import daemon_cmd
from legws_daemon.cli.demo import demo_cmd
from legws_daemon.cli.eval import eval_cmd
from legws_daemon.cli.joystick import joystick_group
from legws_daemon.cli.operator import operator_group
from legws_daemon.cli.optimize import optimize_cmd
from legws_daemon.cli.placement import placement_cmd
from legws_daemon.cli.plan import plan_cmd
from legws_daemon.cli.recording import recording_group
from legws_daemon.cli.render import render_cmd
from legws_daemon.cli.replay import replay_cmd
from legws_daemon.cli.scenes import scenes_cmd
from legws_daemon.cli.secure import secure_group
from legws_daemon.cli.sim_user import sim_user_cmd
from legws_daemon.cli.taskgraph import taskgraph_group
from legws_daemon.cli.track import track_group
from legws_daemon.cli.view import view_cmd
from legws_daemon.errors import LegwsError
from legws_daemon.formats.validation import printable

EXIT_BAD_INPUT = 2


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="legws")
def cli() -> None:
    """legws: certified intent inference and workspace design for shared autonomy."""


cli.add_command(assets_cmd)
cli.add_command(certify_cmd)
cli.add_command(render_cmd)
cli.add_command(scenes_cmd)
cli.add_command(eval_cmd)
cli.add_command(optimize_cmd)
cli.add_command(daemon_cmd)
joystick_group.add_command(sim_user_cmd)
cli.add_command(joystick_group)
cli.add_command(bridge_group)
cli.add_command(replay_cmd)
cli.add_command(recording_group)
cli.add_command(demo_cmd)
cli.add_command(plan_cmd)
cli.add_command(placement_cmd)
cli.add_command(taskgraph_group)
cli.add_command(secure_group)
cli.add_command(view_cmd)
cli.add_command(track_group)
cli.add_command(operator_group)


def _fail(message: str) -> int:
    # one line, and nothing a terminal would act on (a path or a message field may hold
    # escape sequences or bidirectional controls): those are written as Python escapes
    text = printable(" ".join(message.split()))
    click.echo(f"legws: error: {text}", err=True)
    return EXIT_BAD_INPUT


def run(argv: Sequence[str] | None = None) -> int:
    """Run the CLI and return its exit code (used by :func:`main` and the tests)."""
    try:
        result = cli.main(
            args=list(argv) if argv is not None else None, prog_name="legws", standalone_mode=False
        )
    except click.exceptions.Exit as exc:
        return int(exc.exit_code)
    except click.ClickException as exc:
        return _fail(exc.format_message())
    except click.exceptions.Abort:
        click.echo("legws: aborted", err=True)
        return 130
    except LegwsError as exc:
        return _fail(str(exc))
    except RuntimeError as exc:
        # mujoco refuses to import with an unknown MUJOCO_GL: bad input, not a crash
        if "MUJOCO_GL" not in str(exc):
            raise
        return _fail(
            f"{exc}; unset it or use egl (headless, the default) or osmesa "
            "(Debian packages: libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1 libosmesa6)"
        )
    except KeyboardInterrupt:
        click.echo("legws: interrupted", err=True)
        return 130
    return int(result) if isinstance(result, int) else 0


def main() -> None:
    sys.exit(run())
