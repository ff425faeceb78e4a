"""A person's session of a study: their planned steps on the robot, one after another.

:class:`Session` takes the participant's steps from the study's plan (``legws study plan``)
and carries them out with the robot (:mod:`.rig`) and the participant's page
(:mod:`.control`, :mod:`.web`):

- **calibration** (method.md §10): ``legws operator calibrate`` on the first task's scene;
  the page counts the reaches; it writes ``operator.json`` — the model every certificate of
  the session is for and ``optimised_for_operator`` designs for. Then every trial's layout
  is made (the page says so: a layout designed for the person takes minutes);
- **practice and trials**: the page shows the trial and the objects to reach and waits for
  Start; then a daemon runs the trial in its layout, with its assistance and the person's
  operator file, recording to ``recordings/step-NNN.rrd``; the page says go once the daemon
  has started (its ``started`` event: the arm at home) and follows the robot (mode, the
  object acted on). The trial ends when the task is done, at a fault, or at the time limit;
  its row of the trial table comes from the daemon's events (:class:`.outcome.TrialWatch`)
  its per-tick frames (``frames/step-NNN.parquet``) and the effort from the recording (the
  deflection that reached the controller, each tick);
- **questionnaire** after each condition: NASA-TLX and the Likert items on the page; the
  answers are checked (:mod:`.answers`) and join the rows of that condition;
- **break**: the page suggests its length; Continue ends it.

**Pause** (the page's button) stops a trial under way at once — the daemon is stopped, so
the robot is — and keeps its recording as ``step-NNN.interrupted-K.rrd``; the trial runs
again from the start on **Resume**. Progress is saved after every step
(``session.json``, written atomically with the trial table, and the study's table of every
participant's trials so far beside their folders): a session that crashed, or
was stopped with Ctrl-C, starts again with the same command at the step it had not
finished.
"""

from __future__ import annotations

import json
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from legws_daemon.client.client import Client
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.formats.files import output_folder, write_atomic
from legws_daemon.formats.operator_file import OperatorFile, load_operator
from legws_daemon.formats.profile import load_profile_named
from legws_daemon.formats.validation import read_json, validate
from legws_daemon.scene.layout_file import dump_json, layout_to_data
from legws_daemon.study.answers import questionnaire_fields
from legws_daemon.study.certificates import trial_certificates
from legws_daemon.study.control import Control
from legws_daemon.study.frames import Frames, frames_from_recording, frames_path, write_frames
from legws_daemon.study.layouts import Layouts, TrialLayout
from legws_daemon.study.outcome import TrialWatch
from legws_daemon.study.protocol import Protocol
from legws_daemon.study.rig import Child, RigSpec
from legws_daemon.study.rows import trial_row
from legws_daemon.study.schedule import Schedule, Step
from legws_daemon.study.store import write_study_table
from legws_daemon.study.table import write_dictionary, write_table

#: Seconds a trial may run from the daemon's start before it ends as not done.
TRIAL_LIMIT_S = 180.0
#: Seconds a daemon (or the calibration) gets to start (load, certify) before it is an error.
START_TIMEOUT_S = 120.0
#: The session's poll period, s: how often it looks at the robot and the page.
POLL_S = 0.2
STATE_FILE = "session.json"


class SessionRecord(BaseModel):
    """``session.json``: where a participant's session stands."""

    model_config = ConfigDict(extra="forbid")
    schema_version: int = 1
    participant: str
    protocol: str
    protocol_sha256: str
    done: list[Annotated[int, Field(ge=1)]] = []
    interrupted: dict[str, int] = {}
    rows: list[dict[str, Any]] = []
    answers: dict[str, dict[str, Any]] = {}
    #: a rehearsal's population (a simulated participant, :mod:`.rehearse`); ``None``: a
    #: person. A folder is one or the other for good: their data never mix.
    rehearsal: str | None = None


def _drain(client: Client) -> None:
    """Drop the events heard so far (none of them is the step's about to start)."""
    for _ in client.events(timeout=0):
        pass


def _pretty(name: str) -> str:
    return name.replace("_", " ")


class PausedError(Exception):
    """The step under way was stopped by Pause (it runs again on Resume)."""


class Session:
    """One participant's session.

    Args:
        protocol, schedule: the study's protocol and plan (``schedule.steps[participant]``).
        participant: the pseudonym.
        folder: the participant's folder (``STUDY/PXX``).
        rig: how to reach the robot.
        control: what the page shows and asks.
        layouts: makes the trials' layouts (shared optimisation caches).
        trial_limit: seconds a trial may run.
        calibration_targets: reaches of the calibration.
        seed: the calibration's seed.
        clock: monotonic seconds.
        viewer_url: the Rerun web viewer's page (shown beside the instructions), or ``None``.
    """

    def __init__(
        self,
        protocol: Protocol,
        schedule: Schedule,
        participant: str,
        folder: Path,
        rig: RigSpec,
        control: Control,
        layouts: Layouts,
        *,
        trial_limit: float = TRIAL_LIMIT_S,
        calibration_targets: int = 20,
        seed: int = 0,
        clock: Callable[[], float] = time.monotonic,
        viewer_url: str | None = None,
        rehearsal: str | None = None,
    ) -> None:
        if participant not in schedule.steps:
            raise InputError(
                f"{participant} is not a participant of this plan (it has "
                f"{', '.join(list(schedule.steps)[:3])} ... {list(schedule.steps)[-1]})",
                field="--participant",
            )
        self.protocol = protocol
        self.schedule = schedule
        self.participant = participant
        self.folder = folder
        self.rig = rig
        self.control = control
        self.layouts = layouts
        self.trial_limit = trial_limit
        self.calibration_targets = calibration_targets
        self.seed = seed
        self.clock = clock
        self.viewer_url = viewer_url
        self.rehearsal = rehearsal
        self.params = Params()
        self.dt = 1.0 / load_profile_named(rig.profile).control.rate_hz
        self.steps = schedule.steps[participant]
        self.state = self._load_state()
        self._layouts: dict[int, TrialLayout] = {}

    # -- files ----------------------------------------------------------------------------
    @property
    def operator_path(self) -> Path:
        return self.folder / "operator.json"

    def _load_state(self) -> SessionRecord:
        path = self.folder / STATE_FILE
        if not path.exists():
            return SessionRecord(
                participant=self.participant, protocol=self.protocol.name,
                protocol_sha256=self.protocol.sha256, rehearsal=self.rehearsal,
            )  # fmt: skip
        record = validate(SessionRecord, read_json(path, "study session"), str(path))
        if record.protocol_sha256 != self.protocol.sha256 or record.participant != self.participant:
            raise InputError(
                f"is the session of {record.participant} under protocol {record.protocol} "
                f"({record.protocol_sha256[:12]}), not of {self.participant} under this "
                f"protocol ({self.protocol.sha256[:12]})",
                source=str(path), field="protocol_sha256",
            )  # fmt: skip
        if record.rehearsal != self.rehearsal:
            was = (f"a rehearsal's (a participant simulated from {record.rehearsal})"
                   if record.rehearsal else "a person's")  # fmt: skip
            raise InputError(
                f"is {was} session: a person and a rehearsal never share a study folder "
                "(plan the rehearsal into a folder of its own)",
                source=str(path), field="rehearsal",
            )  # fmt: skip
        return record

    def _save(self) -> None:
        output_folder(self.folder)
        likert = len(self.protocol.spec.questionnaires.likert)
        rows = [{**r, **self.state.answers.get(r["condition"], {})} for r in self.state.rows]
        write_table(self.folder, "trials", rows, likert)
        body = {"participant": self.participant, "answers": self.state.answers}
        write_atomic(
            self.folder / "questionnaires.json", (json.dumps(body, indent=1) + "\n").encode()
        )
        write_atomic(
            self.folder / STATE_FILE, (self.state.model_dump_json(indent=1) + "\n").encode()
        )
        write_study_table(self.folder.parent, self.protocol.spec.questionnaires.likert)

    def _person(self) -> OperatorFile | None:
        return load_operator(self.operator_path) if self.operator_path.exists() else None

    # -- the session ----------------------------------------------------------------------
    @property
    def next_step(self) -> Step | None:
        done = set(self.state.done)
        return next((s for s in self.steps if s.index not in done), None)

    def run(self) -> list[dict[str, Any]]:
        """Carry out every step not done yet; returns the trial rows."""
        for folder in ("recordings", "layouts", "logs"):
            output_folder(self.folder / folder)
        self._save()
        with self.rig.client() as client:
            while (step := self.next_step) is not None:
                try:
                    self._step(step, client)
                except PausedError:
                    continue  # paused: wait for resume at the top of the step
                self.state.done.append(step.index)
                self._save()
        write_dictionary(self.folder, self.protocol.spec.questionnaires.likert)
        self.control.show(phase="done", message="The session is complete. Thank you!",
                          **self._progress(None))  # fmt: skip
        return self.state.rows

    def _progress(self, step: Step | None) -> dict[str, Any]:
        trials = [s for s in self.steps if s.kind in ("trial", "practice")]
        done = sum(s.index in set(self.state.done) for s in trials)
        out: dict[str, Any] = {
            "participant": self.participant, "trials_done": done, "trials": len(trials),
            "viewer": self.viewer_url,
        }  # fmt: skip
        if step is not None:
            out.update(step=step.index, steps=len(self.steps), kind=step.kind,
                       condition=step.condition, trial=step.trial)  # fmt: skip
        return out

    def _hold(self, step: Step) -> None:
        """While paused: show it and wait for Resume."""
        if not self.control.pause_requested:
            return
        self.control.show(phase="paused", message="Paused. Press Resume to go on.",
                          **self._progress(step))  # fmt: skip
        while not self.control.wait_resume(POLL_S):
            pass

    def _wait_start(self, step: Step, **view: Any) -> None:
        """Show ``view`` and wait for Start (pausing meanwhile holds)."""
        while True:
            self._hold(step)
            self.control.show(**view, **self._progress(step))
            while not self.control.pause_requested:
                if self.control.wait_start(POLL_S):
                    return

    def _step(self, step: Step, client: Client) -> None:
        self._hold(step)
        if step.kind == "calibration":
            self._calibrate(step, client)
            self._prepare(step)
        elif step.kind in ("practice", "trial"):
            self._trial(step, client)
        elif step.kind == "questionnaire":
            self._questionnaire(step)
        else:
            self._wait_start(
                step, phase="break", seconds=step.break_s,
                message=f"Take a break (about {step.break_s} s). Press Continue when ready.",
            )  # fmt: skip

    # -- calibration ----------------------------------------------------------------------
    def _calibrate(self, step: Step, client: Client) -> None:
        first = next(iter(self.protocol.tasks.values()))
        n = self.calibration_targets
        self._wait_start(
            step, phase="ready", title="Calibration",
            message=(f"The robot learns how you steer: reach {n} targets, one at a time, as "
                     "you would reach for an object. Press Start when ready."),
        )  # fmt: skip
        _drain(client)
        rec = self._fresh(self.folder / "recordings" / "calibration.rrd")
        args = self.rig.calibrate_args(
            self.operator_path, self.participant, first.scene.source, n, self.seed, rec,
            trace=self.folder / "calibration.trace.jsonl",
        )  # fmt: skip
        child = Child(args, self.folder / "logs" / "calibration.log", "the calibration")
        self.control.show(phase="calibrating", message="Steer the hand to the target shown.",
                          reach=0, of=n, **self._progress(step))  # fmt: skip
        try:
            while child.poll() is None:
                _drain(client)
                status = client.next_status(POLL_S)
                if status is not None and status.calibration is not None:
                    shown = status.calibration  # reach k of n is on the way: k - 1 done
                    self.control.update(reach=shown.reach - 1, of=shown.of)
                if self.control.pause_requested:
                    child.stop(signal.SIGINT)
                    self._set_aside(rec, "calibration")
                    raise PausedError
        finally:
            child.stop(signal.SIGINT)
        if child.poll() != 0 or not self.operator_path.exists():
            raise child.failed()

    def _prepare(self, step: Step) -> None:
        """Make every trial's layout now (a person's designed layout takes minutes)."""
        todo = [s for s in self.steps if s.kind in ("practice", "trial")]
        for k, s in enumerate(todo, start=1):
            self.control.show(phase="preparing", done=k - 1, of=len(todo),
                              message="Preparing the layouts of your trials ...",
                              **self._progress(step))  # fmt: skip
            self._layout(s)

    def _layout(self, step: Step) -> TrialLayout:
        if step.index not in self._layouts:
            assert step.task is not None and step.layout_seed is not None
            task = self.protocol.tasks[step.task]
            cond = self.protocol.condition(step.condition) if step.condition else None
            self._layouts[step.index] = self.layouts.for_trial(
                task, cond, step.layout_seed, self._person()
            )
        return self._layouts[step.index]

    # -- trials ---------------------------------------------------------------------------
    def _trial(self, step: Step, client: Client) -> None:
        assert step.task is not None
        task = self.protocol.tasks[step.task]
        cond = self.protocol.condition(step.condition) if step.condition else None
        assist = cond.assist if cond is not None else "commit"
        layout = self._layout(step)
        name = f"step-{step.index:03d}"
        what = "Practice" if step.kind == "practice" else f"Trial {step.trial}"
        reach = ", then ".join(f"the {_pretty(t)}" for t in step.targets)
        info = {"title": f"{what}: {_pretty(step.condition or 'practice')}",
                "targets": list(step.targets)}  # fmt: skip
        self._wait_start(step, phase="ready", **info,
                         message=f"Reach for {reach}. Press Start when ready.")  # fmt: skip
        layout_file = self.folder / "layouts" / f"{name}.json"
        write_atomic(layout_file, dump_json(layout_to_data(layout.layout)).encode())
        plan_dir = layout.plan.directory if layout.plan is not None else None
        rec = self._fresh(self.folder / "recordings" / f"{name}.rrd")
        args = self.rig.daemon_args(
            task.kind, task.argument or task.source, assist, rec,
            layout=layout_file if plan_dir is None else None, plan=plan_dir,
            operator=self.operator_path if self.operator_path.exists() else None,
        )  # fmt: skip
        _drain(client)  # nothing of an earlier process counts
        self.control.show(phase="starting", message="The robot is getting ready ...",
                          **info, **self._progress(step))  # fmt: skip
        child = Child(args, self.folder / "logs" / f"{name}.log", f"the daemon of {name}")
        watch = TrialWatch(step.targets)
        try:
            self._watch(child, client, watch, step, info, f"Go: reach for {reach}.")
        except PausedError:
            child.stop()
            self._set_aside(rec, name)
            raise
        finally:
            child.stop()
        for ev in client.events(timeout=0.5):
            watch.event(ev.kind, ev.detail, ev.stamp)
        outcome = watch.outcome
        frames = self._frames(rec, step)
        if frames is not None:
            outcome.effort_s = float(np.linalg.norm(frames.axes, axis=1).sum() * self.dt)
        if not outcome.completed and watch.notes and outcome.failure:
            outcome.failure += f" ({watch.notes[-1]})"
        person = self._person()
        certs = trial_certificates(
            task, layout.layout_for, self.params,
            person.certify_with if person is not None else None,
        )  # fmt: skip
        self.state.rows.append(
            trial_row(self.protocol, step, self.participant, assist, layout, certs, outcome,
                      hesitation_s=watch.hesitation_s,
                      recording=str(rec.relative_to(self.folder)),
                      frames=frames_path(step.index) if frames is not None else "")
        )  # fmt: skip

    def _watch(
        self, child: Child, client: Client, watch: TrialWatch, step: Step,
        info: dict[str, Any], go: str,
    ) -> None:  # fmt: skip
        """Follow the trial's daemon until the trial is over."""
        launched, launched_wall = self.clock(), time.time()
        begun: float | None = None
        while not watch.over:
            for ev in client.events(timeout=0):
                watch.event(ev.kind, ev.detail, ev.stamp)
            status = client.next_status(POLL_S)
            # this trial's daemon: started after it was launched (not a late status of the
            # previous one); its first status starts the trial if the event did not come
            ours = status is not None and (status.started or 0.0) >= launched_wall - 1.0
            if status is not None and ours and status.started is not None:
                watch.begin(status.started)
            if watch.started is not None and begun is None:
                begun = self.clock()
                self.control.show(phase="running", message=go, **info, **self._progress(step))
            if status is not None and ours and watch.started is not None:
                watch.status(status.gripper_closed, status.stamp)
                self.control.update(mode=status.mode, committed=status.committed,
                                    choice=len(watch.outcome.chosen))  # fmt: skip
            if self.control.pause_requested:
                raise PausedError
            if child.poll() is not None and not watch.over:
                for ev in client.events(timeout=0.5):
                    watch.event(ev.kind, ev.detail, ev.stamp)
                if watch.started is None:
                    raise child.failed()
                watch.give_up(f"the daemon exited (code {child.poll()}): {child.last_line()}")
            now = self.clock()
            if begun is None and now - launched > START_TIMEOUT_S:
                raise InputError(f"{child.what} did not start within {START_TIMEOUT_S:g} s",
                                 source=str(child.log))  # fmt: skip
            if begun is not None and now - begun > self.trial_limit:
                watch.give_up(f"limit: the task was not done within {self.trial_limit:g} s")

    def _frames(self, rec: Path, step: Step) -> Frames | None:
        """The trial's per-tick frames from its recording (the EE, the deflection that
        reached the controller — zero on a tick without input —, the mode), written to
        ``frames/step-NNN.parquet``; ``None`` when the recording holds no tick (the daemon
        never ran a tick) or cannot be read."""
        try:
            frames = frames_from_recording(rec, self.dt)
        except InputError:
            return None
        if not len(frames):
            return None
        output_folder(self.folder / "frames")
        write_frames(self.folder / frames_path(step.index), frames)
        return frames

    def _fresh(self, path: Path) -> Path:
        """``path``, an earlier attempt's file there set aside (a crash mid-trial)."""
        if path.exists():
            self._set_aside(path, path.stem)
        return path

    def _set_aside(self, path: Path, key: str) -> None:
        count = self.state.interrupted.get(key, 0) + 1
        self.state.interrupted[key] = count
        if path.exists():
            path.rename(path.with_name(f"{path.stem}.interrupted-{count}{path.suffix}"))
        self._save()

    # -- questionnaires -------------------------------------------------------------------
    def _questionnaire(self, step: Step) -> None:
        assert step.condition is not None
        fields = [f.as_data() for f in questionnaire_fields(self.protocol.spec.questionnaires)]
        self.control.ask()
        self.control.show(
            phase="questionnaire", title=f"About the last block ({_pretty(step.condition)})",
            message="Please answer every question about the trials you have just done.",
            fields=fields, **self._progress(step),
        )  # fmt: skip
        while (answers := self.control.wait_answers(POLL_S)) is None:
            pass
        self.state.answers[step.condition] = answers
