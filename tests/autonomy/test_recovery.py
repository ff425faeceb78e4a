"""A reset while the robot holds an object, on the real MuJoCo stand-in.

The reset puts the object back where it was taken from (the pick reversed, through the
motion planner, to the EE pose the gripper closed at) and goes home; when that cannot be
done it sets the object down over its spot (or refuses once when no release pose is low
enough). Regression: a 10-min soak's reset timed out in ``approach`` (the desk's mug, a
side grasp: one straight-line move from home that also turned ~2 rad ran the stand-in's
wrist into its joint limit); the put-back now turns in a joint-space move at the carry
height.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from legws_daemon.autonomy.assistant import PRIMITIVE_TIMEOUT, STALL_SECONDS, Assistant
from legws_daemon.autonomy.events import Event, SetDown
from legws_daemon.autonomy.recovery import PUT_BACK_PHASES
from legws_daemon.core.geometry import quat_to_matrix
from legws_daemon.errors import InfeasibleError
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.robot.kinematics import solve_ik
from legws_daemon.robot.motion import Grip, JointMove, Move
from legws_daemon.robot.planner import MotionPlanner
from legws_daemon.robot.world import World
from legws_daemon.safety.envelope import Box
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.grasps import extents
from legws_daemon.task.actions import PlanContext, put_back_plan
from legws_daemon.task.targets import MAX_SET_DOWN_DROP, SET_DOWN_CLEARANCE
from tests.autonomy.rig import Rig, stand_in_profile

DOWN = np.diag([1.0, -1.0, -1.0])
#: A reset that puts an object back takes ~10-23 s of robot time on the stand-in.
RESET_SECONDS = 30.0


@pytest.fixture(scope="module")
def profile() -> ProfileSpec:
    return stand_in_profile()


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


class ResetRig(Rig):
    """The autonomy rig with a reset that watches the safety envelope on every tick."""

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
def make_rig(profile: ProfileSpec) -> Iterator[Callable[..., ResetRig]]:
    rigs: list[ResetRig] = []

    def make(name: str, rate_hz: float | None = None) -> ResetRig:
        p = profile if rate_hz is None else stand_in_profile(rate_hz)
        rig = ResetRig.of(p, name)
        assert isinstance(rig, ResetRig)
        rigs.append(rig)
        return rig

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
    make_rig: Callable[..., ResetRig], graph: str, setup: Callable[[Rig], str]
) -> None:
    rig = make_rig(graph)
    name = setup(rig)
    origin = origin_of(rig, name)
    assert rig.adapter.held == name
    run = rig.reset()
    assert_put_back(rig, run, name, origin)
    assert run.reply["plan"][-5:] == ["reach", "release", "back_off", "up", "home"]


def test_reset_again_and_again_keeps_putting_the_mug_back(
    make_rig: Callable[..., ResetRig],
) -> None:
    """The soak's rhythm: pick, reset, pick again (the arm's posture drifts), reset."""
    rig = make_rig("desk")
    for goal in ("white_mug", "maroon_pen_cup", "white_mug"):
        origin = origin_of(rig, goal)
        rig.commit(goal)
        rig.until(lambda: rig.c.mode == "idle")
        assert_put_back(rig, rig.reset(), goal, origin)


@pytest.mark.parametrize("goal", ["white_mug", "maroon_pen_cup", "black_stapler"])
def test_reset_puts_back_at_the_soaks_50_hz(make_rig: Callable[..., ResetRig], goal: str) -> None:
    """The soak ran the loop at 50 Hz (``--rate 50``): the same, with shorter steps."""
    rig = make_rig("desk", 50.0)
    origin = origin_of(rig, goal)
    rig.commit(goal)
    rig.until(lambda: rig.c.mode == "idle", limit=6000)
    assert_put_back(rig, rig.reset(limit=10000), goal, origin)


def test_reset_right_after_a_load_while_holding(make_rig: Callable[..., ResetRig]) -> None:
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
    make_rig: Callable[..., ResetRig],
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
    make_rig: Callable[..., ResetRig],
) -> None:
    """Joints that do not move (until the set-down begins): the put-back's joint-space
    move stalls; after STALL_SECONDS (not the 20 s timeout) the mug is set down over its
    spot, at the orientation it was carried in, its bottom just above the table."""
    rig = make_rig("desk")
    name = holding_after_the_task(rig)
    origin = origin_of(rig, name)
    rig.adapter.joints_jammed = True

    def unjam(event: Event) -> None:
        if isinstance(event, SetDown):
            rig.adapter.joints_jammed = False

    rig.on_event.append(unjam)
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
    make_rig: Callable[..., ResetRig],
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
    make_rig: Callable[..., ResetRig],
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


# --- the plan ------------------------------------------------------------------------


def test_put_back_plan_turns_in_joint_space_above_the_spot() -> None:
    """The pick reversed: up, a joint-space move to above the pre-grasp pose (the turn
    happens there), straight down, in, release, back off; patience on every move before
    the release."""
    scene = load_scene("desk")
    box = Box(np.array([0.2, -0.55, 0.0]), np.array([0.95, 0.7, 0.6]))
    planner = MotionPlanner(World(scene).twin(), scene.home, box)
    planner.set_layout(scene.default_layout())
    grasp = np.array([0.66, 0.22, 0.07])
    R = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    start = np.array([0.55, 0.0, 0.10])
    box = Box(np.array([0.2, -0.55, 0.0]), np.array([0.95, 0.7, 0.6]))
    q = solve_ik(planner.world.twin(), start, DOWN, planner.q_home).q
    ctx = PlanContext(start, DOWN, q, planner, None, box)
    plan = put_back_plan("white_mug", grasp, R, ctx, patience=STALL_SECONDS)
    assert [p.label for p in plan] == [
        "rise", "carry", "approach", "reach", "release", "back_off"
    ]  # fmt: skip
    rise, carry, approach, reach, release, back_off = plan
    assert isinstance(rise, Move) and isinstance(carry, JointMove)
    assert isinstance(approach, Move) and isinstance(reach, Move)
    assert isinstance(release, Grip) and not release.closed
    assert isinstance(back_off, Move)
    pre = grasp - 0.08 * R[:, 2]
    np.testing.assert_allclose(rise.position, [0.55, 0.0, 0.17])
    np.testing.assert_allclose(rise.rotation, DOWN)  # no turn while rising
    # the joint-space move ends above the pre-grasp pose, turned to the grasp
    planner.world.set_q(carry.q)
    np.testing.assert_allclose(planner.world.ee_position(), [pre[0], pre[1], 0.17], atol=2e-3)
    np.testing.assert_allclose(planner.world.ee_rotation(), R, atol=2e-2)
    np.testing.assert_allclose(approach.position, pre)
    np.testing.assert_allclose(approach.rotation, R)
    np.testing.assert_allclose(reach.position, grasp)
    assert reach.floor == pytest.approx(grasp[2] - 0.004)  # in below the fingertip floor
    np.testing.assert_allclose(back_off.position, pre)
    assert all(p.patience == STALL_SECONDS for p in (rise, carry, approach, reach))
    assert back_off.patience is None  # after the release: only the timeout


def test_a_move_with_patience_fails_early_when_it_makes_no_progress() -> None:
    far = np.array([1.0, 0.0, 0.0])
    q = np.zeros(7)
    patient = Assistant([Move("m", far, DOWN, patience=STALL_SECONDS)], speed=0.1, dt=0.05)
    ticks = 0
    while True:
        ticks += 1
        step = patient.step(q, np.zeros(3), DOWN)  # the robot never moves
        if step.failed:
            break
    assert "no progress" in step.failed
    assert ticks * 0.05 == pytest.approx(STALL_SECONDS, abs=0.06)
    # paused ticks (no joystick input) do not count
    paused = Assistant([Move("m", far, DOWN, patience=STALL_SECONDS)], speed=0.1, dt=0.05)
    for _ in range(200):
        assert paused.step(q, np.zeros(3), DOWN, active=False).failed is None
    # a move that keeps coming closer is not stalled, however slowly it goes
    slow = Assistant([Move("m", far, DOWN, patience=STALL_SECONDS)], speed=0.1, dt=0.05)
    p = np.zeros(3)
    for _ in range(int(3 * STALL_SECONDS / 0.05)):
        assert slow.step(q, p, DOWN).failed is None
        p = p + np.array([0.001, 0.0, 0.0])  # 2 cm/s


def test_a_joint_move_with_patience_fails_early_when_the_arm_does_not_follow() -> None:
    target = np.full(7, 0.5)
    stuck = Assistant([JointMove("j", target, patience=STALL_SECONDS)], speed=0.1, dt=0.05)
    ticks = 0
    while ticks < 200:
        ticks += 1
        step = stuck.step(np.zeros(7), np.zeros(3), DOWN)
        if step.failed:
            break
    assert "no progress" in (step.failed or "")
    assert ticks * 0.05 == pytest.approx(STALL_SECONDS, abs=0.06)
