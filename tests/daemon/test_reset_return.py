"""A reset while the robot holds an object, on the real MuJoCo stand-in.

The reset puts the object back where it was taken from (the pick reversed, to the EE pose
the gripper closed at) and goes home; when that cannot be done it sets the object down
over its spot (or refuses once when no release pose is low enough). Regression: a 10-min
soak's reset timed out in ``approach`` (the desk's mug, a side grasp: one straight-line
move from home that also turned ~2 rad ran the stand-in's wrist into its joint limit).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from legws_daemon.core.geometry import quat_to_matrix
from legws_daemon.core.params import Params
from legws_daemon.daemon.assist import (
    PRIMITIVE_TIMEOUT,
    STALL_SECONDS,
    Assistant,
    Grip,
    Move,
    put_back_plan,
    roll_first,
)
from legws_daemon.daemon.controller import PUT_BACK_PHASES, Controller
from legws_daemon.daemon.inbox import JoystickInbox, Sample
from legws_daemon.daemon.service import catalog_scene, catalog_taskgraph
from legws_daemon.errors import InfeasibleError
from legws_daemon.formats.messages import CommandRequest
from legws_daemon.formats.profile import ProfileSpec, load_profile
from legws_daemon.hardware.sim import SimAdapter
from legws_daemon.safety.envelope import Box
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.grasps import extents
from legws_daemon.scene.scene import Scene
from legws_daemon.task.graph import TaskGraph
from legws_daemon.task.targets import MAX_SET_DOWN_DROP, SET_DOWN_CLEARANCE

PROFILE = Path(__file__).parents[2] / "hw_profiles" / "sim.toml"
LOADERS = (catalog_scene, catalog_taskgraph)
DOWN = np.diag([1.0, -1.0, -1.0])
#: A reset that puts an object back takes ~10-23 s of robot time on the stand-in.
RESET_SECONDS = 30.0


class StandIn(SimAdapter):
    """The stand-in, with a fault switch: a wrist that does not turn (orientation holds
    are ignored, the arm keeps the orientation it has)."""

    wrist_jammed = False

    def _command(self, velocity, hold):  # type: ignore[no-untyped-def]
        super()._command(velocity, None if self.wrist_jammed else hold)


@pytest.fixture(scope="module")
def profile() -> ProfileSpec:
    p = load_profile(PROFILE)
    return p.model_copy(update={"sim": p.sim.model_copy(update={"realtime": False})})


@dataclass
class ResetRun:
    """What happened between a ``reset`` and its end."""

    reply: dict[str, Any]
    seconds: float  # robot time (active ticks)
    events: list[tuple[str, dict[str, Any]]]
    held: str | None  # what the gripper held when the reset began
    released: tuple[np.ndarray, np.ndarray] | None  # the object's pose just before release
    settled: np.ndarray | None  # its position just after

    def warnings(self) -> list[dict[str, Any]]:
        return [d for k, d in self.events if k == "warning"]


class Rig:
    """A controller on the stand-in running a task graph (or a scene's pick), a joystick,
    and the events."""

    def __init__(self, profile: ProfileSpec, name: str) -> None:
        self.profile = profile
        self.events: list[tuple[str, dict[str, Any]]] = []
        self.inbox = JoystickInbox()
        self.seq = 0
        graph: TaskGraph | None
        if name == "desk":
            graph, scene = None, load_scene("desk")
        else:
            graph, scene = catalog_taskgraph(name)
        self.name = name

        def make(sc: Scene) -> StandIn:
            a = StandIn(profile, sc)
            a.connect()
            return a

        self.c = Controller(
            profile, scene, scene.default_layout(), make,
            Params(v_max=profile.control.v_max, dt=1 / profile.control.rate_hz),
            lambda k, d: self.events.append((k, d)), graph=graph,
        )  # fmt: skip

    @property
    def adapter(self) -> StandIn:
        a = self.c.adapter
        assert isinstance(a, StandIn)
        return a

    def sample(self, axes: Any, **buttons: bool) -> Sample:
        self.seq += 1
        msg: dict[str, Any] = {"schema": 1, "seq": self.seq, "stamp": 0.0,
                               "axes": [float(a) for a in axes], "source": "t"}  # fmt: skip
        if buttons:
            msg["buttons"] = buttons
        s = self.inbox.offer(json.dumps(msg).encode(), 0.05 * self.seq)
        assert s is not None
        return s

    def hands_off(self) -> Sample:
        """The dead-man held, the stick centred."""
        return self.sample([0.0, 0.0, 0.0])

    def commit(self, goal: str, limit: int = 2000) -> None:
        """Drive toward ``goal`` until the controller commits to it (confirm at the goal)."""
        c = self.c
        for _ in range(limit):
            if c.mode != "teleop":
                break
            d = c.stage.target(goal).position - self.adapter.read_state().ee_position
            n = float(np.linalg.norm(d))
            c.tick(self.sample(d / n) if n > 0.01 else self.sample([0, 0, 0], confirm=True))
        assert c.mode == "assist"
        assert c.committed == goal

    def drive(self, goal: str, ticks: int) -> None:
        """Steer toward a goal of the current stage (teleop) for a while."""
        for _ in range(ticks):
            if self.c.mode != "teleop":
                return
            d = self.c.stage.target(goal).position - self.adapter.read_state().ee_position
            self.c.tick(self.sample(0.8 * d / max(float(np.linalg.norm(d)), 1e-9)))

    def until(self, done: Callable[[], bool], limit: int = 3000) -> None:
        for _ in range(limit):
            if done():
                return
            self.c.tick(self.hands_off())
        raise AssertionError(f"not reached: mode {self.c.mode}")

    def phase(self) -> str | None:
        a = self.c.assistant
        return a.phase if a is not None else None

    def command(self, command: str, argument: str | None = None) -> dict[str, Any]:
        body: dict[str, Any] = {"schema": 1, "command": command}
        if argument is not None:
            body["argument"] = argument
        return self.c.command(CommandRequest.model_validate(body), *LOADERS)

    def reset(self, limit: int = 4000) -> ResetRun:
        """``reset``, then tick with the dead-man held until the reset ends or fails.

        Every tick checks the safety envelope: the EE stays in the workspace box and no
        command is faster than the adapter's limit.
        """
        n0 = len(self.events)
        held = self.adapter.held
        reply = self.command("reset")
        released: tuple[np.ndarray, np.ndarray] | None = None
        settled = None
        box, v_max = self.adapter.box, self.adapter.v_max
        for ticks in range(1, limit + 1):
            before = self.adapter.object_poses()[held] if held is not None else None
            rec = self.c.tick(self.hands_off())
            assert float(np.linalg.norm(rec.command)) <= v_max + 1e-9
            assert box.contains(self.adapter.read_state().ee_position, 1e-6)
            if held is not None and released is None and self.adapter.held is None:
                assert before is not None
                released = before
                settled = self.adapter.object_poses()[held][0]
            new = self.events[n0:]
            failed = any(k == "warning" and "error" in d for k, d in new)
            if failed or any(k == "reset" for k, _ in new):
                return ResetRun(reply, ticks * self.c.dt, new, held, released, settled)
        raise AssertionError(f"the reset did not end: phase {self.phase()}")


@pytest.fixture
def make_rig(profile: ProfileSpec) -> Iterator[Callable[..., Rig]]:
    rigs: list[Rig] = []

    def make(name: str, rate_hz: float | None = None) -> Rig:
        p = profile
        if rate_hz is not None:
            p = p.model_copy(update={"control": p.control.model_copy(update={"rate_hz": rate_hz})})
        rigs.append(Rig(p, name))
        return rigs[-1]

    yield make
    for r in rigs:
        r.c.shutdown()


def origin_of(rig: Rig, name: str) -> np.ndarray:
    """Where ``name`` stands in the layout (its centre resting on the table)."""
    p = rig.c.scene.poses(rig.c.layout)[name]
    return np.array([p.x, p.y, rig.c.scene.z_center(name)])


def bottom(rig: Rig, name: str, pose: tuple[np.ndarray, np.ndarray]) -> float:
    """Height of the lowest point of the object's box at ``pose``."""
    o = rig.c.scene.objects[name]
    e = np.array(extents(o.shape, tuple(o.size)))
    R = quat_to_matrix(pose[1])
    return float(pose[0][2] - 0.5 * np.abs(R[2]) @ e)


def assert_back_home(rig: Rig, run: ResetRun) -> None:
    """The reset ended: teleop at home, gripper open, nothing held, no failure."""
    c = rig.c
    assert [k for k, _ in run.events][-1] == "reset"
    assert not [d for d in run.warnings() if "error" in d]
    assert c.mode == "teleop"
    assert c.assistant is None
    state = rig.adapter.read_state()
    assert not state.gripper_closed
    assert rig.adapter.held is None
    np.testing.assert_allclose(state.ee_position, c.scene.home.position, atol=0.005)
    assert c.task.held is None
    assert c.task.history == []  # the task starts again
    assert run.seconds < RESET_SECONDS


def assert_put_back(rig: Rig, run: ResetRun, name: str, origin: np.ndarray) -> None:
    """The object was put back: released at its spot, not dropped; no set-down."""
    assert run.held == name
    assert run.reply["plan"][:1] in (["rise"], ["carry"])
    assert not run.warnings()  # no timeout, and no set-down either
    assert run.released is not None and run.settled is not None
    np.testing.assert_allclose(run.released[0], origin, atol=0.01)
    table = rig.c.scene.workspace.table_height
    assert bottom(rig, name, run.released) - table < 0.01  # let go on the table
    np.testing.assert_allclose(run.settled, origin, atol=0.01)
    assert_back_home(rig, run)


# --- held at several phases, in every task graph ---------------------------------------


def holding_after_the_task(rig: Rig) -> str:
    """The desk's single pick: the task is done (idle), the object held at home."""
    rig.commit("white_mug")
    rig.until(lambda: rig.c.mode == "idle")
    assert rig.c.task.held == "white_mug"
    return "white_mug"


def stopped_holding(rig: Rig) -> str:
    holding_after_the_task(rig)
    rig.command("stop")
    assert rig.c.mode == "stopped"
    return "white_mug"


def grasped_not_yet_lifted(rig: Rig) -> str:
    """Right after the gripper closed: the pick's stage is not done yet."""
    rig.commit("maroon_pen_cup")
    rig.until(lambda: rig.phase() == "lift")
    assert rig.c.task.held is None and rig.adapter.held == "maroon_pen_cup"
    return "maroon_pen_cup"


def carried_home_after_the_grasp(rig: Rig) -> str:
    rig.commit("black_stapler")
    rig.until(lambda: rig.phase() == "home")
    for _ in range(10):
        rig.c.tick(rig.hands_off())
    return "black_stapler"


def tea_on_the_way_to_the_cup(rig: Rig) -> str:
    """The next stage (a single candidate) carries it: reset mid-carry."""
    rig.commit("green_tea")
    rig.until(lambda: rig.c.committed == "cup" and rig.phase() == "carry")
    for _ in range(15):
        rig.c.tick(rig.hands_off())
    return "green_tea"


def lego_steered_toward_a_bin(rig: Rig) -> str:
    """The next stage is inferred: the user steers the held brick toward a bin."""
    rig.commit("red_brick")
    rig.until(lambda: rig.c.mode == "teleop")
    assert rig.c.task.held == "red_brick"
    rig.drive("bin_d", 60)
    return "red_brick"


def feeding_dipped_in_the_bowl(rig: Rig) -> str:
    """Mid-dip: the food is in the chocolate."""
    rig.commit("grape")
    rig.until(lambda: rig.c.mode == "teleop")
    rig.commit("chocolate_bowl")
    rig.until(lambda: rig.phase() == "soak")
    return "grape"


@pytest.mark.parametrize(
    ("graph", "setup"),
    [
        ("desk", holding_after_the_task),  # the soak's case: timed out before the fix
        ("desk", stopped_holding),  # timed out too
        ("desk", grasped_not_yet_lifted),  # was dropped from the lift height
        ("desk", carried_home_after_the_grasp),  # was dropped from home height
        ("tea", tea_on_the_way_to_the_cup),
        ("lego", lego_steered_toward_a_bin),
        ("feeding", feeding_dipped_in_the_bowl),
    ],
    ids=lambda v: v if isinstance(v, str) else v.__name__,
)
def test_reset_puts_the_held_object_back_and_goes_home(
    make_rig: Callable[..., Rig], graph: str, setup: Callable[[Rig], str]
) -> None:
    rig = make_rig(graph)
    name = setup(rig)
    origin = origin_of(rig, name)
    assert rig.adapter.held == name
    run = rig.reset()
    assert_put_back(rig, run, name, origin)
    assert run.reply["plan"][-7:] == [
        "reach", "release", "back_off", "up", "tilt_back", "roll_back", "home"
    ]  # fmt: skip


def test_reset_again_and_again_keeps_putting_the_mug_back(
    make_rig: Callable[..., Rig],
) -> None:
    """The soak's rhythm: pick, reset, pick again (the arm's posture drifts), reset."""
    rig = make_rig("desk")
    for goal in ("white_mug", "maroon_pen_cup", "white_mug"):
        origin = origin_of(rig, goal)
        rig.commit(goal)
        rig.until(lambda: rig.c.mode == "idle")
        assert_put_back(rig, rig.reset(), goal, origin)


@pytest.mark.parametrize("goal", ["white_mug", "maroon_pen_cup", "black_stapler"])
def test_reset_puts_back_at_the_soaks_50_hz(make_rig: Callable[..., Rig], goal: str) -> None:
    """The soak ran the loop at 50 Hz (``--rate 50``): the same, with shorter steps."""
    rig = make_rig("desk", 50.0)
    origin = origin_of(rig, goal)
    rig.commit(goal)
    rig.until(lambda: rig.c.mode == "idle", limit=6000)
    assert_put_back(rig, rig.reset(limit=10000), goal, origin)


def test_reset_right_after_a_load_while_holding(make_rig: Callable[..., Rig]) -> None:
    """``load_taskgraph`` mid-task: the stand-in lets go and puts every object at the
    layout; the reset then has nothing to put back and only goes home."""
    rig = make_rig("lego")
    rig.commit("blue_brick")
    rig.until(lambda: rig.c.mode == "teleop")
    assert rig.adapter.held == "blue_brick"
    rig.command("load_taskgraph", "lego")
    assert rig.adapter.held is None
    run = rig.reset()
    assert run.reply["plan"] == ["open", "home"]
    assert_back_home(rig, run)
    np.testing.assert_allclose(
        rig.adapter.object_poses()["blue_brick"][0], origin_of(rig, "blue_brick"), atol=1e-6
    )


def test_the_dead_man_pauses_the_put_back_without_giving_up(
    make_rig: Callable[..., Rig],
) -> None:
    rig = make_rig("desk")
    name = holding_after_the_task(rig)
    origin = origin_of(rig, name)
    rig.command("reset")
    for _ in range(30):
        rig.c.tick(rig.hands_off())
    assert rig.phase() in PUT_BACK_PHASES
    q = rig.adapter.read_state().q
    for _ in range(int(3 * STALL_SECONDS / rig.c.dt)):  # no input: longer than the patience
        rec = rig.c.tick(None)
        np.testing.assert_array_equal(rec.command, 0.0)
    np.testing.assert_array_equal(rig.adapter.read_state().q, q)
    assert rig.c.mode == "assist"
    assert not [k for k, _ in rig.events if k == "warning"]
    rig.events.clear()
    rig.until(lambda: rig.c.mode == "teleop")
    assert rig.events[0][0] == "reset"
    assert not [k for k, _ in rig.events if k == "warning"]
    np.testing.assert_allclose(rig.adapter.object_poses()[name][0], origin, atol=0.01)


# --- when the put-back cannot be done ---------------------------------------------------


def test_a_put_back_that_makes_no_progress_sets_the_object_down_over_its_spot(
    make_rig: Callable[..., Rig],
) -> None:
    """A wrist that does not turn: the put-back's turn stalls; after STALL_SECONDS (not
    the 20 s timeout) the mug is set down over its spot, at the orientation it was
    carried in, its bottom just above the table."""
    rig = make_rig("desk")
    name = holding_after_the_task(rig)
    origin = origin_of(rig, name)
    rig.adapter.wrist_jammed = True
    run = rig.reset()
    [warning] = run.warnings()
    assert warning["reset"] == "set_down"
    assert warning["object"] == name
    assert warning["phase"] in PUT_BACK_PHASES
    assert "no progress" in warning["reason"]
    assert run.released is not None and run.settled is not None
    np.testing.assert_allclose(run.released[0][:2], origin[:2], atol=0.01)
    table = rig.c.scene.workspace.table_height
    assert bottom(rig, name, run.released) - table == pytest.approx(SET_DOWN_CLEARANCE, abs=0.01)
    np.testing.assert_allclose(run.settled[:2], origin[:2], atol=0.01)
    assert_back_home(rig, run)
    assert run.seconds < PRIMITIVE_TIMEOUT


def test_a_grasp_outside_the_workspace_box_is_set_down_at_the_lowest_reachable_pose(
    make_rig: Callable[..., Rig],
) -> None:
    """The envelope was tightened after the pick (the floor raised above the mug's
    grasp): no put-back; set down over the spot as low as the box allows."""
    rig = make_rig("desk")
    name = holding_after_the_task(rig)
    origin = origin_of(rig, name)
    box = rig.adapter.box
    floor = 0.09
    rig.adapter.box = Box(np.array([box.lower[0], box.lower[1], floor]), box.upper)
    run = rig.reset()
    assert "approach" not in run.reply["plan"]
    [warning] = run.warnings()
    assert warning["reset"] == "set_down"
    assert "outside the workspace box" in warning["reason"]
    assert run.released is not None
    np.testing.assert_allclose(run.released[0][:2], origin[:2], atol=0.01)
    table = rig.c.scene.workspace.table_height
    assert bottom(rig, name, run.released) - table <= MAX_SET_DOWN_DROP
    assert_back_home(rig, run)


def test_with_no_release_pose_low_enough_the_reset_is_refused_once(
    make_rig: Callable[..., Rig],
) -> None:
    """Nothing is dropped from high up: the first reset is refused (a person takes the
    object); the second opens the gripper where it is and goes home."""
    rig = make_rig("desk")
    holding_after_the_task(rig)
    box = rig.adapter.box
    rig.adapter.box = Box(np.array([box.lower[0], box.lower[1], 0.25]), box.upper)
    with pytest.raises(InfeasibleError, match="take it from the gripper"):
        rig.command("reset")
    assert rig.c.mode == "idle"
    assert rig.adapter.held == "white_mug"
    run = rig.reset()
    assert run.reply["plan"] == ["open", "home"]
    assert_back_home(rig, run)


# --- the plan as pure math ------------------------------------------------------------


def _rot(axis: list[float], angle: float) -> np.ndarray:
    a = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


@pytest.mark.parametrize(
    "target",
    [
        np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]),  # the mug's side grasp
        DOWN @ _rot([0, 0, 1], 2.0),  # a top grasp: a roll only
        _rot([1, 0, 0], np.pi) @ DOWN,  # approach axis reversed
        _rot([0.3, -0.5, 0.8], 2.5) @ DOWN,
    ],
)
def test_roll_first_splits_a_turn_into_a_roll_then_a_tilt(target: np.ndarray) -> None:
    mid = roll_first(DOWN, target)
    np.testing.assert_allclose(mid.T @ mid, np.eye(3), atol=1e-9)
    np.testing.assert_allclose(mid[:, 2], DOWN[:, 2], atol=1e-9)  # a roll: same approach
    tilt = target @ mid.T  # what is left: a turn about an axis normal to both approaches
    w = np.array([tilt[2, 1] - tilt[1, 2], tilt[0, 2] - tilt[2, 0], tilt[1, 0] - tilt[0, 1]])
    if np.linalg.norm(w) > 1e-9:
        assert abs(w @ DOWN[:, 2]) < 1e-9
        assert abs(w @ target[:, 2]) < 1e-9


def test_put_back_plan_turns_only_above_the_spot() -> None:
    grasp = np.array([0.66, 0.22, 0.07])
    R = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    start = np.array([0.55, 0.0, 0.10])
    plan = put_back_plan(grasp, R, start, DOWN, 0.17, DOWN, STALL_SECONDS)
    assert [p.label for p in plan] == [
        "rise", "carry", "roll", "tilt", "approach", "reach", "release", "back_off", "up",
        "tilt_back", "roll_back",
    ]  # fmt: skip
    moves = {p.label: p for p in plan if isinstance(p, Move)}
    release = plan[6]
    assert isinstance(release, Grip) and not release.closed
    np.testing.assert_allclose(moves["rise"].position, [0.55, 0.0, 0.17])
    np.testing.assert_allclose(moves["carry"].position, [0.58, 0.22, 0.17])  # above pre-grasp
    for name in ("rise", "carry"):
        np.testing.assert_allclose(moves[name].rotation, DOWN)  # no turn while moving
    for name in ("roll", "tilt", "up", "tilt_back", "roll_back"):  # turns: in place, up there
        np.testing.assert_allclose(moves[name].position, moves["carry"].position)
    np.testing.assert_allclose(moves["approach"].position, [0.58, 0.22, 0.07])
    np.testing.assert_allclose(moves["approach"].rotation, R)
    np.testing.assert_allclose(moves["reach"].position, grasp)
    np.testing.assert_allclose(moves["reach"].rotation, R)
    np.testing.assert_allclose(moves["roll_back"].rotation, DOWN)
    assert all(moves[n].patience == STALL_SECONDS for n in PUT_BACK_PHASES)
    assert moves["back_off"].patience is None  # after the release: only the timeout


def test_a_move_with_patience_fails_early_when_it_makes_no_progress() -> None:
    far = np.array([1.0, 0.0, 0.0])
    patient = Assistant([Move("m", far, DOWN, patience=STALL_SECONDS)], speed=0.1, dt=0.05)
    ticks = 0
    while True:
        ticks += 1
        step = patient.step(np.zeros(3), DOWN)  # the robot never moves
        if step.failed:
            break
    assert "no progress" in step.failed
    assert ticks * 0.05 == pytest.approx(STALL_SECONDS, abs=0.06)
    # paused ticks (no joystick input) do not count
    paused = Assistant([Move("m", far, DOWN, patience=STALL_SECONDS)], speed=0.1, dt=0.05)
    for _ in range(200):
        assert paused.step(np.zeros(3), DOWN, active=False).failed is None
    # a move that keeps coming closer is not stalled, however slowly it goes
    slow = Assistant([Move("m", far, DOWN, patience=STALL_SECONDS)], speed=0.1, dt=0.05)
    p = np.zeros(3)
    for _ in range(int(3 * STALL_SECONDS / 0.05)):
        assert slow.step(p, DOWN).failed is None
        p = p + np.array([0.001, 0.0, 0.0])  # 2 cm/s
