"""``legws study analyze``'s report: Markdown and a self-contained HTML page with figures.

The report is a list of blocks (a heading, a paragraph, a table, a figure) rendered twice:
``report.md`` (figures beside it in ``figures/``) and ``report.html`` (figures embedded, one
file to send); ``results.json`` holds every number.
"""

from __future__ import annotations

import base64
import html
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from legws_daemon.errors import InputError
from legws_daemon.formats.files import output_folder, write_atomic
from legws_daemon.study.analysis import (
    MEASURES,
    ModelResult,
    fit_mixed,
    fit_success,
    load_trials,
    power,
    questionnaire_table,
)
from legws_daemon.study.store import existing_plan

if TYPE_CHECKING:
    import pandas as pd

#: The power analysis's target.
TARGET_POWER = 0.8


@dataclass(frozen=True, slots=True)
class Block:
    kind: str  # h1 | h2 | p | table | figure
    text: str = ""
    header: tuple[str, ...] = ()
    rows: tuple[tuple[str, ...], ...] = ()
    path: str = ""


def _num(x: float, digits: int = 2) -> str:
    return "—" if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def _p(p: float) -> str:
    return "< 0.001" if p < 0.001 else f"{p:.3f}"


def _model_table(m: ModelResult, unit: str) -> Block:
    rows = [
        (f"{c} vs {m.reference}", f"{_num(e.estimate)} {unit}", f"[{_num(e.low)}, {_num(e.high)}]",
         _p(e.p))
        for c, e in m.conditions.items()
    ] + [
        (e.term, f"{_num(e.estimate)} {unit}", f"[{_num(e.low)}, {_num(e.high)}]", _p(e.p))
        for e in m.positions
    ]  # fmt: skip
    return Block("table", header=("effect", "estimate", "95 % CI", "p"), rows=tuple(rows))


def _figure_conditions(
    df: pd.DataFrame, order: list[str], measure: str, label: str, path: Path
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    data = [df.loc[df["condition"] == c, measure].dropna().astype(float).to_numpy() for c in order]
    a.boxplot(data, tick_labels=order, showfliers=False)
    rng = np.random.default_rng(0)
    for i, d in enumerate(data, start=1):
        a.scatter(i + rng.uniform(-0.15, 0.15, len(d)), d, s=6, alpha=0.4)
    a.set_ylabel(label)
    a.set_title(f"{label} by condition (every trial)")
    means = df.groupby(["participant", "condition"])[measure].mean().unstack()
    for _, row in means.iterrows():
        b.plot(range(len(order)), [row.get(c, np.nan) for c in order], "-o", ms=3, alpha=0.6)
    b.set_xticks(range(len(order)), order)
    b.set_ylabel(f"participant's mean {label}")
    b.set_title("per participant")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _figure_power(curves: dict[str, dict[int, float]], reference: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    for c, curve in curves.items():
        ns = sorted(curve)
        ax.plot(ns, [curve[n] for n in ns], "-o", label=f"{c} vs {reference}")
    ax.axhline(TARGET_POWER, color="grey", ls="--", lw=1)
    ax.set_xlabel("participants")
    ax.set_ylabel("power (p < 0.05)")
    ax.set_ylim(0, 1.02)
    ax.set_title("time to task: power by simulation")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def analyze(
    folder: Path,
    out: Path,
    *,
    reference: str | None = None,
    power_sims: int = 200,
    seed: int = 0,
) -> dict[str, Any]:
    """Analyse the study in ``folder`` and write the report into ``out``; returns the
    numbers (``results.json``)."""
    df = load_trials(folder)
    plan = existing_plan(folder)
    order = list(plan["conditions"]) if plan else list(dict.fromkeys(df["condition"]))
    order = [c for c in order if c in set(df["condition"])]
    rows_per_block = len(plan["rows"]) if plan else len(order)
    ref = reference if reference is not None else order[0]
    if ref not in order:
        raise InputError(
            f"unknown condition '{ref}'; the study's: {', '.join(order)}", field="--reference"
        )
    output_folder(out)
    output_folder(out / "figures")
    participants = int(df["participant"].nunique())
    blocks: list[Block] = [
        Block("h1", f"Study report: {df['protocol'].iloc[0]}"),
        Block(
            "p",
            f"{participants} participants, {len(df)} trials (practice left out), conditions "
            f"{', '.join(order)}; reference condition **{ref}**. Models: linear mixed-effects "
            "(REML), the condition and its position in the participant's order fixed, the "
            "participant a random intercept; success: a binomial GEE with the participant as "
            "the cluster.",
        ),
    ]
    results: dict[str, Any] = {
        "protocol": str(df["protocol"].iloc[0]),
        "participants": participants,
        "trials": len(df),
        "conditions": order,
        "reference": ref,
        "models": {},
    }
    summary_rows = []
    for c in order:
        part = df[df["condition"] == c]
        summary_rows.append(
            (c, str(part["participant"].nunique()), str(len(part)),
             _num(part["time_to_task_s"].astype(float).mean(), 1),
             _num(part["commit_time_s"].astype(float).mean(), 1),
             f"{100 * part['correct'].astype(bool).mean():.1f} %",
             _num(part["effort_s"].astype(float).mean(), 1) if "effort_s" in part else "—")
        )  # fmt: skip
    blocks += [
        Block("h2", "By condition"),
        Block(
            "table",
            header=(
                "condition",
                "participants",
                "trials",
                "time to task, s",
                "commit time, s",
                "correct",
                "effort, s",
            ),
            rows=tuple(summary_rows),
        ),
    ]
    task_model: ModelResult | None = None
    for measure, label, unit in MEASURES:
        m = fit_mixed(df, measure, ref)
        blocks.append(Block("h2", f"{label.capitalize()} (mixed model)"))
        if m is None:
            blocks.append(Block("p", "Too few values to fit."))
            continue
        if measure == "time_to_task_s":
            task_model = m
        results["models"][measure] = m.as_data()
        blocks += [
            Block(
                "p",
                f"`{m.formula}`, groups: participant; {m.n} trials of {m.participants} "
                f"participants. {ref}: {_num(m.intercept)} {unit} (position 1). Participant "
                f"SD {_num(math.sqrt(max(m.group_var, 0)))} {unit}, residual SD "
                f"{_num(math.sqrt(m.residual_var))} {unit}"
                + ("" if m.converged else "; **the fit did not converge**")
                + (f"; warnings: {'; '.join(m.warnings)}" if m.warnings else "")
                + ".",
            ),
            _model_table(m, unit),
        ]
        fig = out / "figures" / f"{measure}.png"
        _figure_conditions(df, order, measure, f"{label}, {unit}", fig)
        blocks.append(
            Block(
                "figure",
                f"{label}: every trial, and each participant's means",
                path=f"figures/{fig.name}",
            )
        )
    success = fit_success(df, ref)
    results["success"] = success
    blocks.append(Block("h2", "Success (the robot acted on every object asked for)"))
    blocks.append(
        Block(
            "table",
            header=("condition", "k of n", "rate", "95 % Clopper-Pearson"),
            rows=tuple(
                (
                    c,
                    f"{r['k']} of {r['n']}",
                    f"{100 * r['rate']:.1f} %",
                    f"[{100 * r['low']:.1f}, {100 * r['high']:.1f}] %",
                )
                for c, r in success["rates"].items()
            ),
        )
    )
    if success["model"] is not None:
        blocks.append(
            Block(
                "p",
                f"`{success['model']['formula']}` (GEE, binomial, exchangeable, clusters: "
                "participants):",
            )
        )
        blocks.append(
            Block(
                "table",
                header=("condition", "odds ratio", "95 % CI", "p"),
                rows=tuple(
                    (
                        f"{c} vs {ref}",
                        _num(o["odds_ratio"]),
                        f"[{_num(o['low'])}, {_num(o['high'])}]",
                        _p(o["p"]),
                    )
                    for c, o in success["model"]["odds_ratios"].items()
                ),
            )
        )
    else:
        blocks.append(Block("p", f"No model: {success['why']}."))
    q = questionnaire_table(df)
    if not q.empty:
        blocks.append(Block("h2", "Questionnaires"))
        blocks.append(
            Block(
                "table",
                header=("condition", "answers", "raw NASA-TLX (0-100)", "Likert mean"),
                rows=tuple(
                    (
                        c,
                        str(int((q["condition"] == c).sum())),
                        _num(q.loc[q["condition"] == c, "tlx_raw"].astype(float).mean(), 1),
                        _num(q.loc[q["condition"] == c, "likert"].astype(float).mean(), 2),
                    )
                    for c in order
                ),
            )
        )
        for measure, label in (("tlx_raw", "raw NASA-TLX"), ("likert", "Likert mean")):
            m = fit_mixed(q, measure, ref, period=False)
            if m is None:
                continue
            results["models"][measure] = m.as_data()
            blocks.append(
                Block("p", f"{label}: `{m.formula}`, groups: participant, {m.n} answers.")
            )
            blocks.append(_model_table(m, "points"))
    if task_model is not None and power_sims > 0:
        trials = round(len(df) / (participants * len(order)))
        grid = [rows_per_block * k for k in range(1, 9) if rows_per_block * k <= 60]
        grid = sorted({max(2, n) for n in grid})
        curves = power(task_model, order, max(1, trials), grid, power_sims, seed)
        results["power"] = {
            "measure": "time_to_task_s",
            "sims": power_sims,
            "trials_per_condition": trials,
            "curves": {c: {str(n): v for n, v in curve.items()} for c, curve in curves.items()},
        }
        fig = out / "figures" / "power.png"
        _figure_power(curves, ref, fig)
        blocks.append(Block("h2", "Power (time to task)"))
        rows = []
        for c, curve in curves.items():
            enough = [n for n in sorted(curve) if curve[n] >= TARGET_POWER]
            est = task_model.conditions[c].estimate if c in task_model.conditions else 0.0
            rows.append(
                (f"{c} vs {ref}", f"{_num(est)} s",
                 ", ".join(f"{n}: {100 * curve[n]:.0f} %" for n in sorted(curve)),
                 str(enough[0]) if enough else f"more than {max(curve)}")
            )  # fmt: skip
        blocks += [
            Block(
                "p",
                f"Datasets drawn from the fitted time-to-task model ({power_sims} per size, "
                f"{trials} trials per condition, balanced), each refitted: the share of "
                f"p < 0.05. Sizes in multiples of the design's {rows_per_block} orders.",
            ),
            Block(
                "table",
                header=(
                    "contrast",
                    "effect measured",
                    "power by participants",
                    f"participants for {100 * TARGET_POWER:.0f} %",
                ),
                rows=tuple(rows),
            ),
            Block("figure", "power by the number of participants", path="figures/power.png"),
        ]
    write_atomic(
        out / "results.json", (json.dumps(results, indent=1, default=_json) + "\n").encode()
    )
    write_atomic(out / "report.md", markdown(blocks).encode())
    write_atomic(out / "report.html", page(blocks, out).encode())
    return results


def _json(x: Any) -> Any:
    if isinstance(x, np.generic):
        return x.item()
    raise TypeError(type(x).__name__)


def markdown(blocks: list[Block]) -> str:
    out: list[str] = []
    for b in blocks:
        if b.kind == "h1":
            out += [f"# {b.text}", ""]
        elif b.kind == "h2":
            out += [f"## {b.text}", ""]
        elif b.kind == "p":
            out += [b.text, ""]
        elif b.kind == "table":
            out.append("| " + " | ".join(b.header) + " |")
            out.append("|" + "---|" * len(b.header))
            out += ["| " + " | ".join(r) + " |" for r in b.rows]
            out.append("")
        elif b.kind == "figure":
            out += [f"![{b.text}]({b.path})", ""]
    return "\n".join(out)


def _inline(text: str) -> str:
    """Markdown's `code` and **bold** of a paragraph, as HTML (the rest escaped)."""
    parts = html.escape(text).split("`")
    text = "".join(f"<code>{p}</code>" if i % 2 else p for i, p in enumerate(parts))
    parts = text.split("**")
    return "".join(f"<b>{p}</b>" if i % 2 else p for i, p in enumerate(parts))


def page(blocks: list[Block], folder: Path) -> str:
    body: list[str] = []
    title = next((b.text for b in blocks if b.kind == "h1"), "Study report")
    for b in blocks:
        if b.kind in ("h1", "h2"):
            body.append(f"<{b.kind}>{html.escape(b.text)}</{b.kind}>")
        elif b.kind == "p":
            body.append(f"<p>{_inline(b.text)}</p>")
        elif b.kind == "table":
            head = "".join(f"<th>{html.escape(h)}</th>" for h in b.header)
            rows = "".join(
                "<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in b.rows
            )
            body.append(f"<table><thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>")
        elif b.kind == "figure":
            data = base64.b64encode((folder / b.path).read_bytes()).decode()
            body.append(
                f'<figure><img alt="{html.escape(b.text)}" src="data:image/png;base64,{data}">'
                f"<figcaption>{html.escape(b.text)}</figcaption></figure>"
            )
    style = (
        "body{font-family:sans-serif;max-width:60em;margin:2em auto;padding:0 1em}"
        "table{border-collapse:collapse;margin:1em 0}"
        "td,th{border:1px solid #bbb;padding:.25em .6em}"
        "th{background:#eee}img{max-width:100%}code{background:#f4f4f4;padding:0 .2em}"
    )
    return (
        f'<!doctype html><html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}'
        f"</title><style>{style}</style></head><body>{''.join(body)}</body></html>\n"
    )
