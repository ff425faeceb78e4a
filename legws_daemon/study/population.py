"""Populations of simulated participants (``studies/populations/*.toml``).

A population says how people differ: each participant's operator model (method.md §10:
speed, noise, its correlation, aiming bias, steering) is drawn from it, and so are their
hesitation before each reach and how they answer questionnaires. *Planted effects* change
that per condition: a known effect a simulated study must recover (the analysis's check).

```toml
schema_version = 1
name = "lab"
calibration_reaches = 20               # the §10 calibration each session opens with

[operator]                             # truncated normals: mean, sd, low, high
speed = {mean = 0.8, sd = 0.12, low = 0.4, high = 1.0}
sigma = {mean = 0.02, sd = 0.006, low = 0.004, high = 0.06}
rho = {mean = 0.5, sd = 0.2, low = 0.0, high = 0.95}
bias_deg = {mean = 0.0, sd = 6.0, low = -25.0, high = 25.0}
steering = {free = 0.7, axes = 0.2, "axes+diagonals" = 0.1}   # shares

[hesitation]                           # seconds before the first push of a trial
mean = 0.8                             # the population's mean
participant_sd = 0.3                   # participants differ (a random intercept)
trial_sd = 0.2                         # trials of one participant differ

[answers]
tlx = {mean = 40.0, participant_sd = 12.0, noise = 8.0}      # each NASA-TLX subscale, 0-100
likert = {mean = 5.0, participant_sd = 0.8, noise = 0.7}     # each item, 1..likert_points

[effects.optimised]                    # planted: this condition against the others
hesitation_s = -0.5                    # added to every trial's hesitation
speed_scale = 1.0                      # the operator's speed times this
tlx = -8.0                             # added to every subscale
likert = 0.6                           # added to every item
```
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, Strict, model_validator
from scipy.stats import truncnorm

from legws_daemon.core.operator import OperatorModel, Steering
from legws_daemon.errors import InputError
from legws_daemon.formats.positions import SourceText
from legws_daemon.formats.validation import (
    Finite,
    Name,
    did_you_mean,
    parse_toml,
    read_text,
    resolve_named,
    validate,
)

NonNegative = Annotated[float, Strict(), Field(ge=0.0, le=1e6)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Normal(_Model):
    """A normal distribution truncated to ``[low, high]``."""

    mean: Finite
    sd: NonNegative
    low: Finite
    high: Finite

    @model_validator(mode="after")
    def _ordered(self) -> Normal:
        if not self.low <= self.mean <= self.high:
            raise ValueError(
                f"expected low <= mean <= high, got {self.low}, {self.mean}, {self.high}"
            )
        return self

    def draw(self, rng: np.random.Generator) -> float:
        if self.sd == 0 or self.low == self.high:
            return float(self.mean)
        a, b = (self.low - self.mean) / self.sd, (self.high - self.mean) / self.sd
        return float(truncnorm.rvs(a, b, loc=self.mean, scale=self.sd, random_state=rng))


class OperatorDistribution(_Model):
    speed: Normal
    sigma: Normal
    rho: Normal
    bias_deg: Normal
    steering: dict[Literal["free", "axes", "axes+diagonals"], NonNegative] = {"free": 1.0}

    @model_validator(mode="after")
    def _shares(self) -> OperatorDistribution:
        if sum(self.steering.values()) <= 0:
            raise ValueError("steering: expected shares with a positive sum")
        return self


class Hesitation(_Model):
    mean: NonNegative = 0.5
    participant_sd: NonNegative = 0.0
    trial_sd: NonNegative = 0.0


class Answers(_Model):
    mean: Finite
    participant_sd: NonNegative = 0.0
    noise: NonNegative = 0.0


class AnswersSpec(_Model):
    tlx: Answers = Answers(mean=40.0, participant_sd=12.0, noise=8.0)
    likert: Answers = Answers(mean=5.0, participant_sd=0.8, noise=0.7)


class Effect(_Model):
    hesitation_s: Annotated[float, Strict(), Field(ge=-60.0, le=60.0)] = 0.0
    speed_scale: Annotated[float, Strict(), Field(gt=0.0, le=10.0)] = 1.0
    tlx: Annotated[float, Strict(), Field(ge=-100.0, le=100.0)] = 0.0
    likert: Annotated[float, Strict(), Field(ge=-10.0, le=10.0)] = 0.0


class PopulationSpec(_Model):
    schema_version: Literal[1]
    name: Name
    description: str = ""
    calibration_reaches: Annotated[int, Strict(), Field(ge=4, le=200)] = 20
    operator: OperatorDistribution
    hesitation: Hesitation = Hesitation()
    answers: AnswersSpec = AnswersSpec()
    effects: dict[Name, Effect] = {}


@dataclass(frozen=True, slots=True)
class Participant:
    """One simulated participant.

    Attributes:
        pseudonym: who.
        model: how they steer (their true operator model; the study fits its own).
        hesitation_s: their mean hesitation before a trial's first push, s.
        tlx, likert: their baseline answer (every subscale, every item).
    """

    pseudonym: str
    model: OperatorModel
    hesitation_s: float
    tlx: float
    likert: float


@dataclass(frozen=True, slots=True)
class Population:
    spec: PopulationSpec
    source: str

    @property
    def name(self) -> str:
        return self.spec.name

    def effect(self, condition: str | None) -> Effect:
        """The planted effect of ``condition`` (none: the neutral one)."""
        if condition is None:
            return Effect()
        return self.spec.effects.get(condition, Effect())

    def draw(self, pseudonym: str, rng: np.random.Generator) -> Participant:
        """A participant of this population."""
        o = self.spec.operator
        shares = {k: v for k, v in o.steering.items() if v > 0}
        names = list(shares)
        p = np.array([shares[n] for n in names]) / sum(shares.values())
        steering: Steering = names[int(rng.choice(len(names), p=p))]
        model = OperatorModel(
            speed=o.speed.draw(rng),
            sigma=o.sigma.draw(rng),
            rho=o.rho.draw(rng),
            bias_deg=o.bias_deg.draw(rng),
            steering=steering,
        )
        h = self.spec.hesitation
        a = self.spec.answers
        return Participant(
            pseudonym,
            model,
            max(0.0, h.mean + h.participant_sd * float(rng.standard_normal())),
            a.tlx.mean + a.tlx.participant_sd * float(rng.standard_normal()),
            a.likert.mean + a.likert.participant_sd * float(rng.standard_normal()),
        )


def populations_dir() -> Path:
    return Path(__file__).resolve().parents[2] / "studies" / "populations"


def load_population(name_or_path: str | Path, conditions: list[str] | None = None) -> Population:
    """Read and validate a population file (a name in ``studies/populations/`` or a path);
    with ``conditions``, every planted effect must name one of them."""
    path = resolve_named(str(name_or_path), populations_dir(), "population", "--simulate")
    text = read_text(path, "study population")
    where = SourceText(text, "toml")
    spec = validate(PopulationSpec, parse_toml(text, str(path)), str(path), where)
    if conditions is not None:
        for name in spec.effects:
            if name not in conditions:
                guess = did_you_mean(name, conditions)
                hint = f"; did you mean '{guess}'?" if guess else ""
                raise InputError(
                    f"a planted effect for '{name}', which is no condition of the "
                    f"protocol{hint} (its conditions: {', '.join(conditions)})",
                    source=where.at(str(path), ("effects", name)),
                    field=f"effects.{name}",
                )
    return Population(spec, str(path))
