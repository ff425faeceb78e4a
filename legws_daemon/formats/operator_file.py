"""The operator file (interfaces.md, method.md §10): a person's fitted model.

```json
{"schema": 1, "name": "alice", "speed": 0.92, "sigma": 0.031, "rho": 0.83,
 "bias_deg": -4.1, "steering": "free", "segments": 20, "ticks": 3120,
 "intervals": {"speed": [0.9, 0.94], "sigma": [0.029, 0.033], "rho": [0.8, 0.86],
               "bias_deg": [-6.0, -2.2]},
 "certify_with": {"speed": 0.9, "sigma": 0.033, "rho": 0.86, "bias_deg": -6.0,
                  "steering": "free"}}
```

The point estimates, their 95 % bootstrap intervals over segments, and ``certify_with``: the
conservative end of each interval (smaller speed; larger sigma, rho and |bias|), the model
every certificate for this person is computed with. Extra fields (``legws operator fit``
writes how the fit went: ``clipped``, ``axis_share``, ``fit``) are allowed and kept out of
the way. Every error is one line naming the file and the field.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, Strict, model_validator

from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.operator_fit import Fit
from legws_daemon.errors import InputError
from legws_daemon.formats.files import write_atomic
from legws_daemon.formats.positions import SourceText
from legws_daemon.formats.validation import (
    Finite,
    field_error,
    located,
    printable,
    read_json_with_lines,
    validate,
)

#: Names of people: letters, digits and ``_ . -`` (printed in status lines and warnings).
NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.\-]{0,63}$"
OperatorName = Annotated[str, Field(pattern=NAME_PATTERN)]
Interval = tuple[Finite, Finite]
Count = Annotated[int, Strict(), Field(ge=1, le=10**9)]
NUMBERS = ("speed", "sigma", "rho", "bias_deg")


class ModelSchema(BaseModel):
    model_config = ConfigDict(extra="forbid")

    speed: Finite
    sigma: Finite
    rho: Finite
    bias_deg: Finite
    steering: Literal["free", "axes", "axes+diagonals"]


class IntervalsSchema(BaseModel):
    model_config = ConfigDict(extra="allow")

    speed: Interval
    sigma: Interval
    rho: Interval
    bias_deg: Interval

    @model_validator(mode="after")
    def _ordered(self) -> IntervalsSchema:
        for name in NUMBERS:
            lo, hi = getattr(self, name)
            if lo > hi:
                raise field_error((name,), f"expected [low, high], got [{lo}, {hi}]")
        return self


class OperatorSchema(ModelSchema):
    model_config = ConfigDict(extra="allow")

    schema_: Literal[1] = Field(alias="schema")
    name: OperatorName
    segments: Count
    ticks: Count
    intervals: IntervalsSchema
    certify_with: ModelSchema


@dataclass(frozen=True, slots=True)
class OperatorFile:
    """A person's operator file.

    Attributes:
        name: who it describes.
        fitted: the point estimates.
        certify_with: the model certificates for this person use (the conservative ends).
        intervals: name -> (low, high) of ``speed``, ``sigma``, ``rho``, ``bias_deg``.
        segments, ticks: how much teleoperation the fit saw.
        source: the file it was read from ("" when made in memory).
        extra: the file's other fields (how the fit went).
    """

    name: str
    fitted: OperatorModel
    certify_with: OperatorModel
    intervals: dict[str, tuple[float, float]]
    segments: int
    ticks: int
    source: str = ""
    extra: dict[str, Any] | None = None

    def as_data(self) -> dict[str, Any]:
        """The file's JSON object (interfaces.md's fields first, then the extras)."""
        fitted = self.fitted.as_dict()
        return {
            "schema": 1,
            "name": self.name,
            **{k: fitted[k] for k in (*NUMBERS, "steering")},
            "segments": self.segments,
            "ticks": self.ticks,
            "intervals": {k: list(self.intervals[k]) for k in NUMBERS},
            "certify_with": self.certify_with.as_dict(),
            **(self.extra or {}),
        }

    @classmethod
    def from_fit(cls, fit: Fit, name: str, extra: dict[str, Any] | None = None) -> OperatorFile:
        """The file of a fit (``extra``: fields to keep beside the fit's ``fit`` record)."""
        diag = dict(fit.diagnostics)
        record = {
            "fit": {
                k: diag[k]
                for k in ("rim_share", "undid_clip", "seen", "segments_left_out")
                if k in diag
            },
            "axis_share": diag.get("axis_share"),
            "grid_share": diag.get("grid_share"),
            **(extra or {}),
        }
        return cls(name, fit.model, fit.certify_with, dict(fit.intervals), fit.segments,
                   fit.ticks, "", record)  # fmt: skip

    def write(self, path: Path) -> None:
        """Write the file (atomically; refused in one line where no regular file can go)."""
        write_atomic(Path(path), (json.dumps(self.as_data(), indent=2) + "\n").encode())

    def status(self) -> dict[str, Any]:
        """What the daemon's status says of it: ``{"name", "model", "intervals"}``."""
        return {
            "name": self.name,
            "model": self.certify_with.as_dict(),
            "intervals": {k: list(v) for k, v in self.intervals.items()},
        }


def _model(schema: ModelSchema, source: str, where: str) -> OperatorModel:
    try:
        return OperatorModel(
            schema.speed, schema.sigma, schema.rho, schema.bias_deg, schema.steering
        )
    except InputError as err:
        text = str(err).removeprefix(f"{err.field}: ") if err.field else str(err)
        field = f"{where}{err.field}" if err.field else where.rstrip(".")
        raise InputError(text, source=source, field=field) from None


def check_name(name: str, field: str = "name") -> str:
    """``name`` when it is a valid operator name (:data:`NAME_PATTERN`).

    Raises:
        InputError: one line naming ``field``.
    """
    if not re.fullmatch(NAME_PATTERN, name):
        raise InputError(
            f"expected 1-64 letters, digits, _ . - (starting with a letter or digit), got "
            f"{printable(name)!r}",
            field=field,
        )
    return name


def operator_from_data(data: Any, source: str, where: SourceText | None = None) -> OperatorFile:
    """Validate a parsed operator file (a line per error naming ``source``, the line of
    the field when ``where`` holds the file's text, and the field)."""
    doc = validate(OperatorSchema, data, source, where)
    try:
        fitted = _model(doc, source, "")
        certify_with = _model(doc.certify_with, source, "certify_with.")
    except InputError as err:
        raise located(err, where) from None
    intervals = {k: (float(getattr(doc.intervals, k)[0]), float(getattr(doc.intervals, k)[1]))
                 for k in NUMBERS}  # fmt: skip
    extra = {k: v for k, v in data.items() if k not in OperatorSchema.model_fields
             and k != "schema"}  # fmt: skip
    return OperatorFile(
        doc.name, fitted, certify_with, intervals, doc.segments, doc.ticks, source, extra
    )


def load_operator(path: Path) -> OperatorFile:
    """Read and validate an operator file; every error is a line naming file, line and field."""
    data, where = read_json_with_lines(Path(path), "operator")
    return operator_from_data(data, str(path), where)
