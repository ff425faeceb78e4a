"""``legws secure``: an authenticated deployment in one command, and a check of a file.

``legws secure init DIR`` makes a private CA, one identity per role (daemon, operator,
observer, safety, bridge) with the right certificate usages, random passwords, and the
zenoh configuration of each party (:mod:`legws_daemon.transport.access`). ``legws secure
check FILE`` says whether a zenoh configuration is authenticated, as the daemon decides
it for a real arm.
"""

from __future__ import annotations

import json
import secrets
from pathlib import Path

import click

from legws_daemon.errors import InputError
from legws_daemon.formats.files import output_folder
from legws_daemon.formats.printable import echo
from legws_daemon.formats.profile import endpoint_problem

#: What each configuration file is for, and how it is used (its header comment).
USES = {
    "daemon": "legws daemon --profile sawyer --allow-motion --zenoh-config {dir}/daemon.json5",
    "operator": "legws joystick ... --zenoh-config {dir}/operator.json5 (steers, commands)",
    "observer": "dashboards and loggers: status and events, and stop",
    "safety": "a stop button or safety monitor: stop only (put on legws/<robot>/stop/safety)",
    "bridge": "bridge/intera_bridge.py or `legws bridge fake` --zenoh-config {dir}/bridge.json5",
}


def _bracket(host: str) -> str:
    """An IPv6 address in brackets, as endpoints write it."""
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


@click.group("secure")
def secure_group() -> None:
    """Authenticated transport: certificates, passwords, access control."""


@secure_group.command("init")
@click.argument("directory", type=click.Path(path_type=Path, file_okay=False))
@click.option(
    "--host",
    "hosts",
    multiple=True,
    metavar="NAME|ADDRESS",
    help="A name or address clients dial to reach the daemon PC (repeatable; the first is "
    "written into the clients' files). Default: 127.0.0.1 only.",
)
@click.option("--port", type=click.IntRange(1, 65535), default=7447, show_default=True)
@click.option(
    "--listen",
    "listen_address",
    metavar="ADDRESS",
    help="Address the daemon listens on (default: 127.0.0.1 without --host, else 0.0.0.0).",
)
@click.option(
    "--days",
    type=click.IntRange(1, 3650),
    default=825,
    show_default=True,
    help="Validity of the certificates.",
)
def init_cmd(
    directory: Path, hosts: tuple[str, ...], port: int, listen_address: str | None, days: int
) -> None:
    """Create a CA, identities and zenoh configurations for a deployment in DIRECTORY.

    DIRECTORY must be new or empty; nothing is ever overwritten. Keys and files holding
    passwords are readable by their owner only. Copy to each machine its own
    configuration, key and certificate plus certs/ca.pem; keep certs/ca-key.pem offline.
    """
    from legws_daemon.transport.access import CLIENT_ROLES, client_config, daemon_config
    from legws_daemon.transport.pki import ROLES, Authority, host_name, write_new

    for host in hosts:
        host_name(host)  # one line for a bad name
    dial = hosts[0] if hosts else "127.0.0.1"
    listen_host = listen_address or ("0.0.0.0" if hosts else "127.0.0.1")
    listen = f"tls/{_bracket(listen_host)}:{port}"
    connect = f"tls/{_bracket(dial)}:{port}"
    for flag, endpoint in (("--listen", listen), ("--host", connect)):
        problem = endpoint_problem(endpoint)
        if problem is not None:
            raise InputError(problem, field=flag)
    output_folder(directory)  # a file or device in the way: one line
    if any(directory.iterdir()):
        raise InputError(
            "is not empty; `legws secure init` never overwrites", source=str(directory)
        )
    root = directory.resolve()
    certs = root / "certs"
    output_folder(certs)
    root.chmod(0o700)

    ca = Authority.create(days)
    write_new(certs / "ca.pem", ca.cert_pem, 0o644)
    write_new(certs / "ca-key.pem", ca.key_pem, 0o600)
    paths: dict[str, dict[str, str]] = {}
    for role in ROLES:
        identity = ca.issue(role, tuple(hosts) if role == "daemon" else (), days)
        write_new(certs / f"{role}.pem", identity.cert_pem, 0o644)
        write_new(certs / f"{role}-key.pem", identity.key_pem, 0o600)
        paths[role] = {
            "ca": str(certs / "ca.pem"),
            "cert": str(certs / f"{role}.pem"),
            "key": str(certs / f"{role}-key.pem"),
        }
    passwords = {role: secrets.token_urlsafe(24) for role in CLIENT_ROLES}
    credentials = root / "credentials.txt"
    write_new(credentials, "".join(f"{r}:{p}\n" for r, p in passwords.items()).encode(), 0o600)

    configs: dict[str, dict[str, object]] = {
        "daemon": daemon_config([listen], paths["daemon"], str(credentials))
    }
    for role in CLIENT_ROLES:
        configs[role] = client_config(role, [connect], paths[role], passwords[role])
    for name, config in configs.items():
        header = (
            f"// legws {name}: written by `legws secure init` (do not share: it holds a "
            f"password or names the key).\n// Use: {USES[name].format(dir=root)}\n"
        )
        write_new(root / f"{name}.json5", (header + json.dumps(config, indent=2)).encode(), 0o600)

    echo(f"legws secure init: a CA and {len(ROLES)} identities in {root}")
    echo(f"  daemon listens on {listen}; the others dial {connect}")
    for role in ROLES:
        echo(f"  {role + '.json5':15s} {USES[role].format(dir=root)}")
    echo(f"  certs/ca-key.pem signs new certificates: keep it offline ({days} days valid)")


@secure_group.command("check")
@click.argument("config_file", type=click.Path(path_type=Path, dir_okay=False))
def check_cmd(config_file: Path) -> None:
    """Say whether a zenoh configuration is authenticated (TLS endpoints, mutual TLS or
    user/password, access control denying by default); exit 2 if it is not."""
    from legws_daemon.transport.security import authentication_problem
    from legws_daemon.transport.session import config_from_file

    problem = authentication_problem(config_from_file(config_file))
    if problem is not None:
        raise InputError(f"not authenticated: {problem}", source=str(config_file))
    echo(f"{config_file}: authenticated (TLS, peer authentication, access control)")
