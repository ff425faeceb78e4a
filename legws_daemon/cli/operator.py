"""``legws operator``: a person's operator model (method.md §10) — a trace of their
teleoperation from a recording, the fit of the model to traces, a calibration."""

from __future__ import annotations

from pathlib import Path

import click

from legws_daemon.cli.operator_calibrate import calibrate_cmd
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.formats.files import output_path
from legws_daemon.formats.operator_file import NUMBERS, OperatorFile
from legws_daemon.formats.printable import echo
from legws_daemon.formats.profile import load_profile_named


@click.group("operator")
def operator_group() -> None:
    """The operator model of a person: trace, fit, calibrate (docs/operator.md)."""


def profile_params(profile: str) -> Params:
    """The model parameters of a hardware profile: its ``v_max`` and control period."""
    spec = load_profile_named(profile)
    return Params(v_max=spec.control.v_max, dt=1.0 / spec.control.rate_hz)


@operator_group.command("trace")
@click.argument("recording", type=click.Path(path_type=Path, dir_okay=False))
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(path_type=Path, dir_okay=False),
    help="The trace to write (JSON Lines, interfaces.md).",
)
def trace_cmd(recording: Path, out: Path) -> None:
    """Write the teleoperation trace of a daemon RECORDING (.rrd): one segment per decision
    that completed after a commit (its teleoperation up to the commit, toward the committed
    goal) and per calibration reach."""
    from legws_daemon.formats.trace import write_trace
    from legws_daemon.telemetry.operator_trace import recorded_segments

    output_path(out)
    segments = recorded_segments(recording)
    ticks = write_trace(out, segments)
    echo(f"legws: {len(segments)} segments, {ticks} ticks -> {out}", err=True)


@operator_group.command("fit")
@click.argument("traces", nargs=-1, required=True, type=click.Path(path_type=Path, dir_okay=False))
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(path_type=Path, dir_okay=False),
    help="The operator file to write (JSON, interfaces.md).",
)
@click.option(
    "--name",
    default="operator",
    show_default=True,
    help="Whom the model describes (letters, digits, _ . -; shown in status and warnings).",
)
@click.option(
    "--profile",
    default="sim",
    show_default=True,
    help="The hardware profile the traces were recorded on (its v_max and control rate).",
)
@click.option(
    "--resamples",
    type=click.IntRange(100, 100_000),
    default=1000,
    show_default=True,
    help="Bootstrap resamples of segments for the 95 %% intervals.",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the bootstrap.")
def fit_cmd(
    traces: tuple[Path, ...], out: Path, name: str, profile: str, resamples: int, seed: int
) -> None:
    """Fit a person's operator model to TRACES (JSON Lines from `legws operator trace` or
    `legws operator calibrate`): speed, noise, its correlation, aiming bias and steering
    with 95 % bootstrap intervals over segments, and the conservative ends certificates for
    them use (certify_with)."""
    from legws_daemon.core.operator_fit import fit_operator
    from legws_daemon.formats.operator_file import check_name
    from legws_daemon.formats.trace import read_trace

    check_name(name, "--name")
    output_path(out)
    params = profile_params(profile)
    segments = [(s.ee, s.u, s.goal) for path in traces for s in read_trace(path)]
    try:
        fit = fit_operator(segments, params, resamples=resamples, seed=seed)
    except InputError as err:
        where = ", ".join(str(p) for p in traces)
        raise InputError(str(err).removeprefix("segments: "), source=where) from None
    record = OperatorFile.from_fit(fit, name, {"traces": [str(p) for p in traces]})
    record.write(out)
    echo(describe(record))
    echo(f"legws: wrote {out}", err=True)


def describe(record: OperatorFile) -> str:
    """The fit in a few lines: the estimates with their intervals, certify_with."""
    units = {"speed": "", "sigma": " m/s", "rho": "", "bias_deg": "°"}
    lines = [
        f"operator {record.name}: {record.segments} segments, {record.ticks} ticks, "
        f"steering {record.fitted.steering}"
    ]
    for key in NUMBERS:
        value = getattr(record.fitted, key)
        lo, hi = record.intervals.get(key, (value, value))
        lines.append(f"  {key:9s} {value:8.4f}{units[key]}  95 % [{lo:.4f}, {hi:.4f}]")
    lines.append(f"  certify with: {record.certify_with.describe()}")
    return "\n".join(lines)


operator_group.add_command(calibrate_cmd)
