"""What legws reads back from a daemon recording (``.rrd``), validated as any file is.

A recording is input like any other: it may come from another machine, a newer legws, a
damaged disk or an adversary. Every document in it is parsed with
:func:`~legws_daemon.formats.validation.parse_json` (a key given twice, control and
bidirectional characters and excessive nesting are refused) and validated with the models
here, with the ranges the same data has on disk:

* :class:`StageDoc`, the ``meta/goals`` and ``meta/stages`` document of a stage (one
  ``log_setup``): the telemetry format version (an integer in ``1..supported``), the stage
  index (an integer >= 0), the threshold ``p_thresh`` in (0, 1), names of at most 64
  characters, the goal set's own schema (:class:`~legws_daemon.formats.goalset.GoalSetFile`:
  positions in the cell, non-zero quaternions, 2 to ``MAX_GOALS`` goals) and its parameters
  (:class:`~legws_daemon.formats.goalset.ParamsSchema`, then the ranges of
  :class:`~legws_daemon.core.params.Params`);
* :class:`CommitRow`, a commit line of the text log (the goal's name, ``p`` in [0, 1]);
* the per-tick values (an EE position in the cell, as
  :data:`~legws_daemon.formats.scene_file.CellPosition`; ticks up to :data:`MAX_TICK`,
  stage indices up to :data:`MAX_STAGE`, text rows up to :data:`MAX_ROW` characters),
  checked column by column where they are read (:mod:`legws_daemon.telemetry.recording`).

Every error is one :class:`~legws_daemon.errors.InputError` naming the file, the document
(``meta/goals``, ``meta/stages`` at a tick, ``log`` at a tick) and the field.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    Strict,
    StrictBool,
    model_validator,
)

from legws_daemon.core.goals import MAX_GOALS
from legws_daemon.errors import InputError
from legws_daemon.formats.goalset import GoalSchema, ParamsSchema, PoseSchema
from legws_daemon.formats.log_lines import How
from legws_daemon.formats.messages import Label
from legws_daemon.formats.scene_file import MAX_OBJECTS, CellXY
from legws_daemon.formats.validation import (
    Angle,
    ManyInputsError,
    field_error,
    parse_json,
    printable,
    validate,
)

#: Largest stage index: a set-up a second for 30 years.
MAX_STAGE = 2**30
#: Largest tick: exact as a float (2**53 ticks at 50 Hz are 5.7 million years).
MAX_TICK = 2**53
#: Longest text of a document or a text-log row, characters (a stage document of the
#: largest goal set is ~40 KiB).
MAX_TEXT = 1024 * 1024
#: Longest row of the text log, characters.
MAX_ROW = 64 * 1024

#: A threshold in (0, 1).
Threshold = Annotated[float, Strict(), Field(gt=0.0, lt=1.0, allow_inf_nan=False)]
#: A probability in [0, 1].
Probability = Annotated[float, Strict(), Field(ge=0.0, le=1.0, allow_inf_nan=False)]


def _printable(value: str) -> str:
    """A name is one printable line (no line break or tab: it is printed in reports)."""
    if not value.isprintable():
        raise ValueError("expected a name of printable characters (no line break or tab)")
    return value


#: A name of 1 to 64 printable characters (a stage's, a scene's, a robot's, a goal's).
Name = Annotated[Label, AfterValidator(_printable)]


class PlannedPose(BaseModel):
    """An object's planned place on the table."""

    model_config = ConfigDict(extra="forbid")

    x: CellXY
    y: CellXY
    yaw: Angle


class StageDoc(BaseModel):
    """The document of one stage (``meta/goals``, ``meta/stages``)."""

    model_config = ConfigDict(extra="forbid")

    legws_telemetry: Annotated[int, Strict(), Field(ge=1)]
    stage_index: Annotated[int, Strict(), Field(ge=0, le=MAX_STAGE)]
    stage: Name | None = None
    robot: Name | None = None
    scene: Name | None = None
    p_thresh: Threshold | None = None
    #: False: a decision without inference (a single candidate): no goal set.
    inference: StrictBool = True
    candidates: Annotated[list[Name], Field(min_length=1, max_length=MAX_GOALS)] | None = None
    goal_objects: Annotated[dict[Name, Name], Field(max_length=MAX_GOALS)] = {}
    planned: Annotated[dict[Name, PlannedPose], Field(max_length=MAX_OBJECTS)] = {}
    params: ParamsSchema = ParamsSchema()
    x0: PoseSchema | None = None
    goals: Annotated[list[GoalSchema], Field(min_length=2, max_length=MAX_GOALS)] | None = None

    @model_validator(mode="after")
    def _complete(self) -> StageDoc:
        for i, goal in enumerate(self.goals or []):
            if not goal.name.isprintable():
                raise field_error(
                    ("goals", i, "name"),
                    f"expected a name of printable characters, got {printable(goal.name)!r}",
                )
        if self.inference:
            for key in ("x0", "goals"):
                if getattr(self, key) is None:
                    raise field_error((key,), "Field required (a stage with inference)")
        elif self.candidates is None:
            raise field_error(("candidates",), "Field required (a stage without inference)")
        return self


class CommitRow(BaseModel):
    """A ``commit goal=<name> p=<prob>`` line of the text log."""

    model_config = ConfigDict(extra="forbid")

    goal: Name
    p: Probability
    how: Literal["inferred", "confirmed", "single"]


def parse_stage_doc(text: Any, source: str, supported: int) -> tuple[StageDoc, dict[str, Any]]:
    """The stage document ``text`` (of ``source``: the file and the entity) and its parsed
    JSON, of a telemetry format up to ``supported``.

    Raises:
        InputError: not text, too long, not JSON (a key given twice, a control character,
            nested too deeply), not an object, of another format, or a field out of range.
    """
    if not isinstance(text, str):
        raise InputError(f"not legws telemetry (expected text, got {type(text).__name__})",
                         source=source)  # fmt: skip
    if len(text) > MAX_TEXT:
        raise InputError(
            f"not legws telemetry (a document of {len(text)} characters, more than {MAX_TEXT})",
            source=source,
        )
    try:
        data = parse_json(text, source, None)
    except InputError as err:
        raise InputError(f"not legws telemetry ({_reason(err, source)})", source=source,
                         field=err.field) from None  # fmt: skip
    if not isinstance(data, dict):
        raise InputError(
            f"not legws telemetry (expected a JSON object, got {type(data).__name__})",
            source=source,
        )
    version = data.get("legws_telemetry")
    if "legws_telemetry" not in data:
        raise InputError("not legws telemetry (no format version)", source=source,
                         field="legws_telemetry")  # fmt: skip
    if type(version) is not int or not 1 <= version <= supported:
        shown = repr(version) if len(repr(version)) <= 40 else repr(version)[:37] + "..."
        raise InputError(
            f"telemetry format {shown} is not supported (this legws reads 1 to {supported})",
            source=source,
            field="legws_telemetry",
        )
    if "stage_index" not in data:
        raise InputError("not legws telemetry (no stage_index)", source=source)
    try:
        return validate(StageDoc, data, source), data
    except InputError as err:
        raise one_line(err) from None


def one_line(err: InputError) -> InputError:
    """``err`` as one error of one line: every error of a :class:`ManyInputsError` after the
    first without the source they share (a recording's error is one line, as a field of a
    message's is)."""
    if not isinstance(err, ManyInputsError):
        return err
    first, *rest = err.errors
    prefix = f"{first.source}: " if first.source else ""
    others = [str(e).removeprefix(prefix) for e in rest]
    message = "; ".join([_reason(first, first.source or ""), *others])
    return InputError(message, source=first.source, field=first.field)


def _reason(err: InputError, source: str) -> str:
    prefix = ": ".join(p for p in (err.source, err.field) if p)
    text = str(err)
    return text.removeprefix(f"{prefix}: ") if prefix else text


def commit_row(goal: str, p: float, how: How, source: str) -> CommitRow:
    """A commit line's fields, validated (``source``: the file and where the line is)."""
    return validate(CommitRow, {"goal": goal, "p": p, "how": how}, source)
