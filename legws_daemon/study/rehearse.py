"""A rehearsal: a simulated participant in a person's session, over zenoh, in real time.

``legws study run PROTOCOL --participant P01 --simulate POPULATION`` runs the session of a
person (:mod:`.session`: a daemon per trial on the profile's robot, the recordings, the
page) with a participant drawn from the population in their place, as
:func:`~legws_daemon.study.simulate.simulate_participant` would draw P01 — so a lab runs its
whole set-up (profile, transport, viewer, the files it publishes) before the first person
comes, and the result is a real session's folder (the draw:
:func:`~legws_daemon.study.simulate.draw_participant`).

The :class:`SimulatedPerson` does what a person does with the page and the stick: it reads
what the page shows (:class:`~legws_daemon.study.control.Control`), presses Start when a
step waits for it, steers with a ``legws joystick sim-user`` publisher of its own — their
operator model (with the condition's planted speed scale), the objects asked for, a new
process per step, started before Start is pressed and pushing only after their hesitation
of that trial from the new daemon's first status (``--onset``) — and answers each
questionnaire as
the simulator does (:func:`~legws_daemon.study.simulate.answers`). The session cannot tell
it from a person: its commits, times and effort are measured from the daemon as for one.
"""

from __future__ import annotations

import _thread
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from legws_daemon.errors import LegwsError
from legws_daemon.study.answers import questionnaire_fields
from legws_daemon.study.control import Control
from legws_daemon.study.population import Participant, Population
from legws_daemon.study.protocol import Protocol
from legws_daemon.study.rig import Child, RigSpec
from legws_daemon.study.simulate import answers, trial_hesitation, with_effect

#: How often the simulated participant looks at the page, s.
LOOK_S = 0.1


class SimulatedPerson:
    """A simulated participant at the page and the stick (a thread; see the module).

    Args:
        person: who (their operator model, hesitation and answers).
        population: their population (the planted effects, the answers' spread).
        protocol: the study's protocol (the questionnaire).
        control: the session's page state.
        rig: how publishers reach the robot.
        folder: where the publishers' logs go.
        rng: their draws (hesitations, answers).
    """

    def __init__(
        self,
        person: Participant,
        population: Population,
        protocol: Protocol,
        control: Control,
        rig: RigSpec,
        folder: Path,
        rng: np.random.Generator,
    ) -> None:
        self.person = person
        self.population = population
        self.protocol = protocol
        self.control = control
        self.rig = rig
        self.folder = folder
        self.rng = rng
        self.error: str | None = None
        self._stop = threading.Event()
        self._stick: Child | None = None
        self._thread = threading.Thread(target=self._run, name="simulated-person", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(10.0)
        self._let_go()

    def _let_go(self) -> None:
        if self._stick is not None:
            self._stick.stop()
            self._stick = None

    def _stick_args(self, view: dict[str, Any]) -> list[str]:
        m = with_effect(
            self.person.model, self.population.effect(view.get("condition")).speed_scale
        )
        args = ["joystick", "sim-user", "--profile", self.rig.profile]
        if self.rig.zenoh_config is not None:
            args += ["--zenoh-config", str(self.rig.zenoh_config)]
        args += ["--speed", f"{m.speed:.4f}", "--rho", f"{m.rho:.4f}", "--bias",
                 f"{m.bias_deg:.4f}", "--steering", m.steering, "--sigma", f"{m.sigma:.5f}",
                 "--seed", str(int(self.rng.integers(2**31))), "--wait-daemon", "600"]  # fmt: skip
        for target in view.get("targets") or []:
            args += ["--goal", str(target)]
        if not view.get("targets"):
            args.append("--forever")  # the calibration: every target shown
        return args

    def _run(self) -> None:
        try:
            self._act()
        except LegwsError as err:  # the session would wait for it for ever: stop it
            self.error = str(err)
            _thread.interrupt_main()

    def _act(self) -> None:
        q = self.protocol.spec.questionnaires
        done: set[tuple[Any, ...]] = set()
        while not self._stop.is_set():
            view = self.control.view()
            key = (view.get("phase"), view.get("step"), view.get("version"))
            phase = view.get("phase")
            if view.get("paused") or phase in ("done", "failed"):
                self._let_go()
            elif phase == "ready" and key not in done:
                done.add(key)
                self._let_go()
                onset = (
                    trial_hesitation(self.person, self.population, view.get("condition"), self.rng)
                    if view.get("targets")
                    else 0.0
                )
                log = self.folder / f"stick-{view.get('step')}.log"
                args = [*self._stick_args(view), "--onset", f"{onset:.3f}"]
                self._stick = Child(args, log, "the simulated stick")
                self.control.start()
            elif phase == "questionnaire" and key not in done:
                done.add(key)
                self._let_go()
                condition = str(view.get("condition"))
                given = answers(self.person, self.population, condition, len(q.likert),
                                q.likert_points, self.rng)  # fmt: skip
                asked = {f.name for f in questionnaire_fields(q)}
                self.control.submit({k: v for k, v in given.items() if k in asked})
            elif phase == "break" and key not in done:
                done.add(key)
                self.control.start()
            time.sleep(LOOK_S)
