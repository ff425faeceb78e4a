"""The analysis of a study: mixed-effects models, a model of success, questionnaires, power.

What a within-subject study needs and what pooled rank tests get wrong (repeated trials of
one person are not independent):

- **time to task and commit time**: linear mixed-effects models (statsmodels ``MixedLM``,
  REML), ``y ~ condition + position`` with a random intercept per participant — the
  condition a fixed effect against the reference condition, the position of the condition in
  the participant's order a fixed period effect (what counterbalancing balances, here
  estimated and held apart), the participant a random effect;
- **success** (the robot acted on every object asked for): a binomial GEE with the
  participant as the cluster (exchangeable working correlation, robust errors), reported as
  odds ratios; where every trial of a condition succeeded no model can be fitted, and the
  Clopper-Pearson bound of its k of n is given instead;
- **questionnaires**: the raw NASA-TLX (mean of the six subscales) and the mean Likert score,
  one answer per participant and condition, each with the same mixed model (no period);
- **power** by simulation: datasets drawn from the fitted time-to-task model (its fixed
  effects, participant variance and residual variance), balanced, for growing numbers of
  participants, each refitted; the share whose contrast has p < 0.05.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from legws_daemon.core.montecarlo import clopper_pearson
from legws_daemon.errors import InputError

if TYPE_CHECKING:
    import pandas as pd

#: The measures modelled with the mixed model: column, name, unit.
MEASURES = (
    ("time_to_task_s", "time to task", "s"),
    ("commit_time_s", "commit time", "s"),
)
ALPHA = 0.05


@dataclass(frozen=True, slots=True)
class Effect:
    """One fixed effect of a model: ``term`` (a condition against the reference, or a
    position), its estimate with the 95 % interval, and the p-value."""

    term: str
    estimate: float
    low: float
    high: float
    p: float


@dataclass
class ModelResult:
    """A fitted mixed model of one measure.

    Attributes:
        measure: the column modelled; ``formula`` the model.
        n, participants: observations and participants used.
        reference: the reference condition; ``intercept``: its mean (position 1).
        conditions: the condition effects (one per other condition).
        positions: the period effects.
        group_var, residual_var: the participant and residual variances.
        converged: statsmodels' verdict.
    """

    measure: str
    formula: str
    n: int
    participants: int
    reference: str
    intercept: float
    conditions: dict[str, Effect]
    positions: list[Effect]
    group_var: float
    residual_var: float
    converged: bool
    warnings: list[str] = field(default_factory=list)

    def as_data(self) -> dict[str, Any]:
        return {
            "measure": self.measure,
            "formula": self.formula,
            "n": self.n,
            "participants": self.participants,
            "reference": self.reference,
            "intercept": self.intercept,
            "conditions": {c: _effect(e) for c, e in self.conditions.items()},
            "positions": [_effect(e) for e in self.positions],
            "group_var": self.group_var,
            "residual_var": self.residual_var,
            "converged": self.converged,
            "warnings": self.warnings,
        }


def _effect(e: Effect) -> dict[str, float | str]:
    return {"term": e.term, "estimate": e.estimate, "low": e.low, "high": e.high, "p": e.p}


def load_trials(folder: Path) -> pd.DataFrame:
    """The study's trial table: ``folder/trials.parquet``, else every participant's
    ``folder/P*/trials.parquet`` together; practice trials left out."""
    import pandas as pd

    from legws_daemon.study.table import read_table

    whole = folder / "trials.parquet"
    if whole.is_file():
        rows = read_table(whole)
    else:
        parts = sorted(folder.glob("*/trials.parquet"))
        if not parts:
            raise InputError(
                "no trials.parquet in the folder or its participants' folders", source=str(folder)
            )
        rows = [r for p in parts for r in read_table(p)]
    df = pd.DataFrame(rows)
    needed = {"participant", "kind", "condition", "position", "correct"} | {m for m, *_ in MEASURES}
    missing = sorted(needed - set(df.columns))
    if missing:
        raise InputError(f"the trial table lacks columns {missing}", source=str(folder))
    df = df[df["kind"] == "trial"].copy()
    if df.empty:
        raise InputError("the trial table holds no trials (only practice)", source=str(folder))
    return df


def _term(condition_term: str) -> str:
    # "C(condition, Treatment('a'))[T.b]" -> "b"
    return condition_term.rsplit("[T.", 1)[1].rstrip("]")


def _fit(data: pd.DataFrame, formula: str) -> tuple[Any, list[str]]:
    import statsmodels.formula.api as smf

    caught: list[str] = []
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        model = smf.mixedlm(formula, data, groups=data["participant"]).fit(reml=True)
    for w in seen:
        text = str(w.message).split("\n")[0]
        if text not in caught:
            caught.append(text)
    return model, caught


def fit_mixed(
    df: pd.DataFrame, measure: str, reference: str, *, period: bool = True
) -> ModelResult | None:
    """The mixed model of ``measure`` (module text); ``None`` when there is too little to
    fit (fewer than two participants or two conditions with values)."""
    data = df[["participant", "condition", "position", measure]].dropna()
    data = data.astype({measure: float})
    if data["participant"].nunique() < 2 or data["condition"].nunique() < 2:
        return None
    if reference not in set(data["condition"]):
        return None
    formula = f"{measure} ~ C(condition, Treatment({reference!r}))"
    if period and data["position"].nunique() > 1:
        formula += " + C(position)"
    model, caught = _fit(data, formula)
    ci = model.conf_int(ALPHA)
    conditions: dict[str, Effect] = {}
    positions: list[Effect] = []
    for term in model.fe_params.index:
        eff = Effect(
            term, float(model.fe_params[term]), float(ci.loc[term, 0]), float(ci.loc[term, 1]),
            float(model.pvalues[term]),
        )  # fmt: skip
        if term.startswith("C(condition"):
            conditions[_term(term)] = Effect(_term(term), eff.estimate, eff.low, eff.high, eff.p)
        elif term.startswith("C(position"):
            positions.append(
                Effect(f"position {_term(term)}", eff.estimate, eff.low, eff.high, eff.p)
            )
    return ModelResult(
        measure, formula, len(data), int(data["participant"].nunique()), reference,
        float(model.fe_params["Intercept"]), conditions, positions,
        float(np.asarray(model.cov_re)[0, 0]), float(model.scale), bool(model.converged), caught,
    )  # fmt: skip


def fit_success(df: pd.DataFrame, reference: str) -> dict[str, Any]:
    """Success per condition (k of n, Clopper-Pearson) and, where some trial failed, the
    binomial GEE's odds ratios against ``reference``."""
    import statsmodels.api as sm
    import statsmodels.formula.api as smf

    data = df[["participant", "condition", "correct"]].dropna().copy()
    data["ok"] = data["correct"].astype(bool).astype(int)
    rates = {}
    for cond, part in data.groupby("condition", sort=False):
        k, n = int(part["ok"].sum()), len(part)
        lo, hi = clopper_pearson(k, n)
        rates[str(cond)] = {"k": k, "n": n, "rate": k / n, "low": lo, "high": hi}
    out: dict[str, Any] = {"rates": rates, "model": None, "why": ""}
    if data["ok"].nunique() < 2:
        out["why"] = "every trial succeeded" if data["ok"].all() else "no trial succeeded"
        return out
    if any(r["k"] in (0, r["n"]) for r in rates.values()):
        out["why"] = (
            "a condition where every trial (or none) succeeded separates the data: no "
            "odds ratio is finite; the Clopper-Pearson intervals compare them"
        )
        return out
    formula = f"ok ~ C(condition, Treatment({reference!r}))"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = smf.gee(
            formula, "participant", data, family=sm.families.Binomial(),
            cov_struct=sm.cov_struct.Exchangeable(),
        ).fit()  # fmt: skip
    ci = model.conf_int(ALPHA)
    ratios = {}
    for term in model.params.index:
        if term.startswith("C(condition"):
            ratios[_term(term)] = {
                "odds_ratio": math.exp(model.params[term]),
                "low": math.exp(ci.loc[term, 0]),
                "high": math.exp(ci.loc[term, 1]),
                "p": float(model.pvalues[term]),
            }
    out["model"] = {"formula": formula, "odds_ratios": ratios}
    return out


def questionnaire_table(df: pd.DataFrame) -> pd.DataFrame:
    """One row per participant and condition: ``tlx_raw`` and ``likert`` (the items' mean)."""
    import pandas as pd

    likert = [c for c in df.columns if c.startswith("likert_")]
    cols = ["participant", "condition", "position"]
    if "tlx_raw" not in df.columns:
        return pd.DataFrame(columns=[*cols, "tlx_raw", "likert"])
    q = df[[*cols, "tlx_raw", *likert]].dropna(subset=["tlx_raw"])
    q = q.groupby(["participant", "condition"], sort=False).first().reset_index()
    q["likert"] = q[likert].astype(float).mean(axis=1) if likert else np.nan
    return q[[*cols, "tlx_raw", "likert"]]


def power(
    model: ModelResult,
    conditions: Sequence[str],
    trials: int,
    grid: Sequence[int],
    sims: int,
    seed: int = 0,
) -> dict[str, dict[int, float]]:
    """Power of each condition contrast of ``model`` by simulation: for each number of
    participants in ``grid``, ``sims`` datasets of ``trials`` trials per condition drawn from
    the fitted model (no period effect: a balanced design), each refitted; the share with
    p < 0.05."""
    import pandas as pd

    rng = np.random.default_rng(seed)
    effects = {
        c: model.conditions[c].estimate if c in model.conditions else 0.0 for c in conditions
    }
    sd_u, sd_e = math.sqrt(max(model.group_var, 0.0)), math.sqrt(max(model.residual_var, 1e-12))
    out: dict[str, dict[int, float]] = {c: {} for c in conditions if c != model.reference}
    cond = np.repeat(np.array(list(conditions)), trials)
    for n in grid:
        hits = dict.fromkeys(out, 0)
        for _ in range(sims):
            u = rng.normal(0.0, sd_u, n)
            y = (
                model.intercept
                + np.tile([effects[c] for c in cond], n)
                + np.repeat(u, len(cond))
                + rng.normal(0.0, sd_e, n * len(cond))
            )
            data = pd.DataFrame(
                {
                    "participant": np.repeat([f"S{k}" for k in range(n)], len(cond)),
                    "condition": np.tile(cond, n),
                    "position": 1,
                    "y": y,
                }
            )
            res = fit_mixed(data, "y", model.reference, period=False)
            if res is None:
                continue
            for c in out:
                if c in res.conditions and res.conditions[c].p < ALPHA:
                    hits[c] += 1
        for c in out:
            out[c][n] = hits[c] / sims
    return out
