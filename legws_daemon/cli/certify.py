"""``legws certify``: the trajectory-margin certificate of a goal set or a scene layout, and
with ``--commit`` the commit certificate (method.md §9)."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any, TypeVar

import click
import numpy as np

from legws_daemon.core.certificate import Certificate, certify
from legws_daemon.core.commit import (
    COMMIT_FORMS,
    CommitCertificate,
    certify_commit,
    clipped_user,
    unclipped_user,
)
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.montecarlo import (
    CONFIDENCE,
    MAX_TRIALS,
    MAX_WORK,
    GoalAccuracy,
    GoalCommitRate,
    check_trials,
    monte_carlo,
    monte_carlo_commit,
)
from legws_daemon.core.params import COST_FORMS, RANGES, CostForm, Params, range_problem
from legws_daemon.core.user_model import SimulatedUser
from legws_daemon.errors import InputError
from legws_daemon.formats.files import write_atomic
from legws_daemon.formats.goalset import goalset_to_data, load_goalset
from legws_daemon.formats.operator_file import load_operator
from legws_daemon.formats.printable import echo
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.constraints import require_feasible
from legws_daemon.scene.layout_file import dump_json, load_layout


def certificate_report(
    cert: Certificate,
    params: Params,
    mc: dict[str, GoalAccuracy] | None,
    mc_settings: dict[str, Any] | None,
    source: str,
) -> dict[str, Any]:
    """The JSON object printed by ``legws certify --json`` (interfaces.md, plus extras)."""
    out: dict[str, Any] = {
        "objective": cert.objective,
        "pairs": [asdict(p) for p in cert.pairs],
        "certified": cert.certified,
        "quantile": cert.quantile,
        "source": source,
        "params": params.as_dict(),
    }
    if mc is not None:
        out["monte_carlo"] = {name: asdict(acc) for name, acc in mc.items()}
        out["monte_carlo_settings"] = mc_settings
    return out


def commit_report(cert: CommitCertificate, mc: dict[str, GoalCommitRate] | None) -> dict[str, Any]:
    """The ``commit`` (and ``monte_carlo_commit``) fields of ``legws certify --commit``. A
    goal the operator's nominal never reaches (method.md §10) has ``reachable: false`` and
    ``null`` for its fraction and slacks; ``objective`` (K) is then ``null`` too."""
    tau_c, tau_w = cert.thresholds
    goals = {}
    for name, g in cert.goals.items():
        entry = asdict(g)
        if not g.reachable:
            entry |= {"fraction": None, "slack_at_arrival": None, "wrong_commit_slack": None}
        goals[name] = entry
    out: dict[str, Any] = {
        "commit": {
            "objective": cert.objective if math.isfinite(cert.objective) else None,
            "certified": cert.certified,
            "goals": goals,
            "tau_commit": tau_c,
            "tau_wrong": tau_w,
            "quantile": cert.quantile,
        }
    }
    if mc is not None:
        out["monte_carlo_commit"] = {name: asdict(r) for name, r in mc.items()}
    return out


F = TypeVar("F", bound=Callable[..., Any])


def require_finite(value: Any, where: str = "") -> None:
    """Refuse a report holding a non-finite number (JSON has none, and no certificate is
    infinite): one line naming the field, before anything is printed.

    Raises:
        InputError: naming the first non-finite field.
    """
    if isinstance(value, float) and not math.isfinite(value):
        raise InputError(
            f"is {value}: the certificate is not finite for these parameters "
            "(check alpha, beta, sigma and the goal positions)",
            field=where or "(report)",
        )
    if isinstance(value, dict):
        for k, v in value.items():
            require_finite(v, f"{where}.{k}" if where else str(k))
    elif isinstance(value, list | tuple):
        for i, v in enumerate(value):
            require_finite(v, f"{where}[{i}]")


def _param_option(name: str, unit: str) -> Callable[[F], F]:
    """``--NAME``: override the goal set's (or the default) parameter, within
    :data:`~legws_daemon.core.params.RANGES` (one-line error outside, with the reason)."""
    lo, hi = RANGES[name]

    def check(_ctx: click.Context, _param: click.Parameter, value: float | None) -> float | None:
        if value is not None and not (math.isfinite(value) and lo <= value <= hi):
            raise click.BadParameter(range_problem(name, value))
        return value

    return click.option(
        f"--{name}",
        type=float,
        callback=check,
        metavar="X",
        help=f"Override {name}{unit}, in [{lo:g}, {hi:g}].",
    )


def _table(rows: list[list[str]], header: list[str]) -> str:
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]

    def line(r: list[str]) -> str:
        cells = zip(r, widths, strict=True)
        return "  ".join(c.ljust(w) if i < 2 else c.rjust(w) for i, (c, w) in enumerate(cells))

    return "\n".join([line(header), line(["-" * w for w in widths]), *map(line, rows)])


def render_text(report: dict[str, Any], goals: GoalSet) -> str:
    p = report["params"]
    who = report.get("operator")
    whom = (
        f"for operator {who['name']} ({_model_text(who['model'])}"
        f"{', the robot clipping |u| <= 1' if who['clipped'] else ''})"
        if who
        else "for section 2's simulated user (white noise, aimed straight, full deflection)"
    )
    lines = [
        f"Certificate of {report['source']}: M = {goals.m}, cost {p['cost']}, beta {p['beta']}, "
        f"alpha {p['alpha']}, z = {report['quantile']:.3f}",
        whom,
        "",
        _table(
            [
                [
                    q["true"],
                    q["other"],
                    f"{q['margin']:.3f}",
                    f"{q['variance']:.4f}",
                    f"{q['slack']:.3f}",
                    str(q["steps"]),
                ]
                for q in report["pairs"]
            ],
            ["true", "other", "margin", "variance", "slack", "steps"],
        ),
        "",
        f"objective J = {report['objective']:.4f}: "
        + (
            f"CERTIFIED, every goal wins at the horizon with probability >= {1 - p['alpha']:.2f}"
            if report["certified"]
            else "NOT certified (J <= 0)"
        ),
    ]
    mc = report.get("monte_carlo")
    if mc:
        s = report["monte_carlo_settings"]
        lines += [
            "",
            f"Monte Carlo: {s['trials']} trials per goal, seed {s['seed']}, "
            f"{'speed clipped to v_max' if s['clip_speed'] else 'unclipped user model'}, "
            f"{int(CONFIDENCE * 100)}% Clopper-Pearson interval",
            "",
            _table(
                [
                    [
                        name,
                        "",
                        f"{a['accuracy']:.4f}",
                        f"[{a['lower95']:.4f}, {a['upper95']:.4f}]",
                        "yes" if a["accuracy"] >= 1 - p["alpha"] else "NO",
                    ]
                    for name, a in mc.items()
                ],
                ["goal", "", "accuracy", "95% interval", f">= {1 - p['alpha']:.2f}"],
            ),
        ]
    commit = report.get("commit")
    if commit:
        lines += ["", *_commit_text(report, goals)]
    return "\n".join(lines)


def _model_text(model: dict[str, Any]) -> str:
    return (
        f"s {model['speed']:.2f}, sigma {model['sigma']:.3f} m/s, rho {model['rho']:.2f}, "
        f"bias {model['bias_deg']:+.1f}°, {model['steering']}"
    )


def _commit_text(report: dict[str, Any], goals: GoalSet) -> list[str]:
    c = report["commit"]
    p = report["params"]

    def num(x: float | None, digits: int = 3) -> str:
        return "—" if x is None else f"{x:.{digits}f}"

    rows = []
    for name in goals.names:
        g = c["goals"][name]
        crossing = g["crossing_step"]
        rows.append(
            [
                name,
                "",
                num(g["fraction"]),
                "—" if crossing is None else str(crossing),
                str(g["arrival_steps"]) if g["reachable"] else "never",
                num(g["slack_at_arrival"]),
                num(g["wrong_commit_slack"]),
                "—" if g["progress"] is None else f"{100 * g['progress']:.0f} %",
                "yes" if g["certified"] else "NO",
            ]
        )
    if report.get("operator"):
        user = f"operator {report['operator']['name']}" + (
            ", robot's clip" if c["user"]["clipped"] else ""
        )
    else:
        user = "speed-clipped user" if c["user"]["clipped"] else "unclipped user of §2"
    form = "exact-sum form" if c["form"] == "sum" else "even split"
    k = c["objective"]
    lines = [
        f"Commit certificate (method.md §9, {user}, {form}): commit at p >= {p['p_thresh']}, "
        f"tau_c = {c['tau_commit']:.3f}, tau_w = {c['tau_wrong']:.3f}, z_c = {c['quantile']:.3f}",
        "",
        _table(
            rows,
            [
                "goal",
                "",
                "kappa",
                "commit step",
                "arrival",
                "c(T_a)",
                "w",
                "of the way",
                "certified",
            ],
        ),
        "",
        f"commit objective K = {num(k, 4)}, {c['certified']} of {goals.m} goals "
        "commit-certified: "
        + (
            f"every goal's first commit is on it by step t_c with probability >= "
            f"{1 - p['alpha']:.2f}"
            if k is not None and k <= 1.0
            else "NOT every goal (K > 1)"
            if k is not None
            else "NOT every goal (a goal the operator does not reach)"
        ),
    ]
    mc = report.get("monte_carlo_commit")
    if mc:
        lines += [
            "",
            _table(
                [
                    [
                        name,
                        "",
                        str(r["by_step"]),
                        f"{r['rate_by_step']:.4f}",
                        f"{r['lower95']:.4f}",
                        f"{r['wrong']:.4f}",
                        f"{r['before_arrival']:.4f}",
                    ]
                    for name, r in mc.items()
                ],
                ["goal", "", "by step", "commit rate", "lower 95%", "wrong", "before arrival"],
            ),
        ]
    return lines


@click.command("certify")
@click.argument("goals_file", required=False, type=click.Path(path_type=Path))
@click.option("--scene", help="Certify a scene's layout instead of a goal-set file.")
@click.option(
    "--layout",
    "layout_file",
    type=click.Path(path_type=Path),
    help="Layout JSON for --scene (default: the scene's shipped layout).",
)
@click.option("--cost", type=click.Choice(COST_FORMS), help="Override the cost form.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object (interfaces.md).")
@_param_option("alpha", " (the accepted failure probability)")
@_param_option("beta", " (the observer's rationality)")
@_param_option("sigma", " (the user's velocity noise, m/s)")
@click.option(
    "--monte-carlo",
    "trials",
    type=click.IntRange(min=1, max=MAX_TRIALS),
    help=f"Also simulate N noisy users per goal and report accuracy at the horizon (N at most "
    f"{MAX_TRIALS:,}, and N x goals x steps at most {MAX_WORK:.3g}, about a minute: "
    "the error names the largest N for the goal set).",
)
@click.option(
    "--seed", type=int, default=0, show_default=True, help="Seed of the Monte Carlo check."
)
@click.option(
    "--operator",
    "operator_file",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Certify for a person: an operator file (legws operator fit|calibrate); the "
    "certificates use its certify_with model (method.md §10) with the robot's clip, and "
    "--monte-carlo simulates that operator.",
)
@click.option(
    "--clip-speed/--no-clip-speed",
    default=None,
    help="The robot's speed clip |v| <= v_max: in the Monte Carlo, and in the commit "
    "certificate of that slower user (with --operator: in every certificate). Default: off "
    "for section 2's user, on with --operator.",
)
@click.option(
    "--commit",
    "with_commit",
    is_flag=True,
    help="Add the commit certificate (method.md §9) and, with --monte-carlo, its check.",
)
@click.option(
    "--commit-form",
    type=click.Choice(COMMIT_FORMS),
    default="min",
    show_default=True,
    help="With --commit: the commit slack of method.md §9 (min: the budget split evenly over "
    "the alternatives) or its exact-sum form (tighter, same promise).",
)
@click.option(
    "--export-goals",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Write the certified goal set as a goal-set file.",
)
def certify_cmd(
    goals_file: Path | None,
    scene: str | None,
    layout_file: Path | None,
    cost: CostForm | None,
    as_json: bool,
    alpha: float | None,
    beta: float | None,
    sigma: float | None,
    trials: int | None,
    seed: int,
    operator_file: Path | None,
    clip_speed: bool | None,
    with_commit: bool,
    commit_form: str,
    export_goals: Path | None,
) -> None:
    """Certify GOALS_FILE (a goal-set JSON) or a scene layout (--scene).

    Prints every ordered pair's margin, variance, slack and horizon, and the objective J;
    J > 0 certifies that the true goal is the observer's argmax at the horizon with
    probability at least 1 - alpha for every goal. With --commit, also the commit
    certificate: per goal the certified commit step and its fraction of the way, and
    K = the largest fraction (K <= 1: every goal's first commit is on it by then with
    probability at least 1 - alpha).
    """
    if (goals_file is None) == (scene is None):
        raise click.UsageError("give either GOALS_FILE or --scene NAME")
    if layout_file is not None and scene is None:
        raise click.UsageError("--layout needs --scene")
    if scene is not None:
        sc = load_scene(scene)
        layout = load_layout(layout_file, sc) if layout_file else sc.default_layout()
        require_feasible(sc, layout, str(layout_file) if layout_file else sc.source)
        goals = sc.goal_set(layout)
        params = Params()
        source = f"scene {sc.name} ({layout_file or 'default layout'})"
    else:
        assert goals_file is not None
        goals, params = load_goalset(goals_file)
        source = str(goals_file)
    if cost is not None:
        params = params.with_cost(cost)
    if alpha is not None:
        params = replace(params, alpha=alpha)
    if beta is not None:
        params = replace(params, beta=beta)
    if sigma is not None:
        params = replace(params, sigma=sigma)
    person = load_operator(operator_file) if operator_file is not None else None
    clip = clip_speed if clip_speed is not None else person is not None
    operator = person.certify_with if person is not None else None
    # who the Monte Carlo simulates: the operator certified, or section 2's user (clipped)
    who = SimulatedUser(operator, clip=clip) if operator is not None else None
    if trials is not None:
        check_trials(
            goals, params, trials, commit_forms=int(with_commit), clip_speed=clip, user=who,
            field="--monte-carlo",
        )  # fmt: skip

    # section 2's user keeps section 4's J (the clip only in its Monte Carlo and commit)
    user = operator.motion(params, clip) if operator is not None else None
    cert = certify(goals, params, operator, user)
    mc = settings = None
    if trials is not None:
        mc = monte_carlo(goals, params, trials, seed, clip_speed=clip, user=who)[params.cost]
        settings = {
            "trials": trials,
            "seed": seed,
            "clip_speed": clip,
            "confidence": CONFIDENCE,
            "simulated": "operator (certify_with)" if who is not None else "section 2's user",
        }
    report = certificate_report(cert, params, mc, settings, source)
    if person is not None:
        report["operator"] = {
            "name": person.name,
            "source": person.source,
            "model": person.certify_with.as_dict(),
            "clipped": clip,
        }
    if with_commit:
        # with --clip-speed the commit is certified for the robot's slower, clipped user
        motion = user
        if motion is None:
            motion = clipped_user(params) if clip else unclipped_user(params)
        commit = certify_commit(goals, params, motion, commit_form, operator)
        rates = None
        if trials is not None:
            steps = [commit.goals[n].step for n in goals.names]
            rng = np.random.default_rng([seed, 9])
            rates = monte_carlo_commit(goals, params, trials, rng, steps, clip_speed=clip, user=who)
        report |= commit_report(commit, rates)
        report["commit"]["user"] = asdict(motion) | {"clipped": clip}
        report["commit"]["form"] = commit_form
    require_finite(report)
    if export_goals is not None:
        write_atomic(export_goals, dump_json(goalset_to_data(goals, params)).encode())
    if as_json:
        click.echo(json.dumps(report, allow_nan=False))  # ASCII: every other character escaped
    else:
        echo(render_text(report, goals))
