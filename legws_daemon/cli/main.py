"""Entry point of ``legws``: the command group and the error policy.

Bad input of any kind (a usage error, a file or field that does not validate, an
unknown name, a path the operating system refuses) prints ``legws: error: ...`` on stderr
and exits 2: one line per error (a file with three wrong fields: three lines, each
``FILE:LINE: field: ...``). Nothing the user can cause prints a traceback.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Sequence

import click

from legws_daemon import __version__
from legws_daemon.cli.lazy import LazyGroup
from legws_daemon.errors import LegwsError
from legws_daemon.formats.printable import MESSAGE_LIMIT, guard_last_resort, safe_text
from legws_daemon.formats.validation import error_lines

EXIT_BAD_INPUT = 2


#: every command: its name and where it is defined (``module:attribute``). A command's module
#: is imported when the command runs (or ``--help`` lists it): ``legws joystick keyboard``
#: does not load the optimiser, the renderer or rerun.
COMMANDS: dict[str, str] = {
    "assets": "legws_daemon.cli.assets:assets_cmd",
    "bridge": "legws_daemon.cli.bridge:bridge_group",
    "certify": "legws_daemon.cli.certify:certify_cmd",
    "daemon": "legws_daemon.cli.daemon:daemon_cmd",
    "demo": "legws_daemon.cli.demo:demo_cmd",
    "eval": "legws_daemon.cli.eval:eval_cmd",
    "joystick": "legws_daemon.cli.joystick:joystick_group",
    "operator": "legws_daemon.cli.operator:operator_group",
    "optimize": "legws_daemon.cli.optimize:optimize_cmd",
    "placement": "legws_daemon.cli.placement:placement_cmd",
    "plan": "legws_daemon.cli.plan:plan_cmd",
    "recording": "legws_daemon.cli.recording:recording_group",
    "render": "legws_daemon.cli.render:render_cmd",
    "replay": "legws_daemon.cli.replay:replay_cmd",
    "scenes": "legws_daemon.cli.scenes:scenes_cmd",
    "secure": "legws_daemon.cli.secure:secure_group",
    "study": "legws_daemon.cli.study:study_group",
    "taskgraph": "legws_daemon.cli.taskgraph:taskgraph_group",
    "track": "legws_daemon.cli.track:track_group",
    "view": "legws_daemon.cli.view:view_cmd",
}


@click.group(
    cls=LazyGroup,
    lazy=COMMANDS,
    context_settings={"help_option_names": ["-h", "--help"]},
)
@click.version_option(__version__, prog_name="legws")
def cli() -> None:
    """legws: certified intent inference and workspace design for shared autonomy."""


def _fail(*messages: str) -> int:
    # one line each, and nothing a terminal would act on (a path or a message field may
    # hold escape sequences or bidirectional controls): those are written as Python escapes,
    # and a line too long is cut
    for message in messages:
        text = safe_text(" ".join(message.split()), MESSAGE_LIMIT)
        click.echo(f"legws: error: {text}", err=True)
    return EXIT_BAD_INPUT


def run(argv: Sequence[str] | None = None) -> int:
    """Run the CLI and return its exit code (used by :func:`main` and the tests)."""
    guard_last_resort()  # a log record no handler takes is printed safe too
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
        return _fail(*error_lines(exc))
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
    except BrokenPipeError:  # ``legws ... | head``: the reader left; nothing to say
        with contextlib.suppress(OSError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except OSError as exc:
        # a path the system refuses (a name too long, a loop of links, no permission) that
        # reached a call outside the readers and writers of formats.files
        if exc.filename is None:
            raise
        what = exc.strerror or type(exc).__name__
        return _fail(f"{os.fsdecode(exc.filename)}: {what}")
    return int(result) if isinstance(result, int) else 0


def main() -> None:
    sys.exit(run())
