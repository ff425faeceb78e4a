"""The shipped scenes: paper tiers, demo object sets, feasible default layouts."""

from __future__ import annotations

import numpy as np
import pytest

from legws_daemon.core.certificate import certify
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.scene.catalog import load_scene, scene_names
from legws_daemon.scene.constraints import LayoutConstraints
from legws_daemon.scene.grasps import extents
from tests.expected import DEMOS, PAPER_TIERS


def test_all_scenes_are_shipped() -> None:
    assert set(scene_names()) == set(PAPER_TIERS) | set(DEMOS)


@pytest.mark.parametrize("name", sorted(PAPER_TIERS))
def test_paper_tiers_have_the_papers_counts(name: str) -> None:
    sc = load_scene(name)
    tier, m, total = PAPER_TIERS[name]
    assert (sc.spec.tier, len(sc.goal_names), len(sc.objects)) == (tier, m, total)


def test_all_tiers_share_one_workspace_and_home() -> None:
    workspaces = {load_scene(n).workspace for n in scene_names()}
    assert len(workspaces) == 1


@pytest.mark.parametrize("name", sorted([*PAPER_TIERS, *DEMOS]))
def test_default_layout_is_feasible_and_objects_sit_on_the_table(name: str) -> None:
    sc = load_scene(name)
    cons = LayoutConstraints.of(sc)
    layout = sc.default_layout()
    assert cons.problems(layout) == []
    assert cons.violation(cons.from_layout(layout)[None])[0] == 0.0
    ws = sc.workspace
    for o in sc.objects.values():
        ex = extents(o.shape, tuple(o.size))
        half = max(ex[0], ex[1]) / 2
        assert abs(o.x - ws.table_center[0]) + half <= ws.table_size[0] / 2, o.name
        assert abs(o.y - ws.table_center[1]) + half <= ws.table_size[1] / 2, o.name
    goals = sc.goal_set()
    assert np.all(
        np.isfinite([certify(goals, Params(cost=c)).objective for c in ("dragan", "ratio")])
    )


def test_demo_object_sets() -> None:
    tea = load_scene("tea")
    assert {"black_tea", "green_tea", "chamomile_tea", "cup", "plate"} <= set(tea.objects)
    assert set(tea.goal_names) == {"black_tea", "green_tea", "chamomile_tea"}
    lego = load_scene("lego")
    assert sum(n.endswith("_brick") for n in lego.objects) >= 3
    assert sum(n.startswith("bin_") for n in lego.objects) >= 3
    feeding = load_scene("feeding")
    assert {"strawberry", "grape", "brownie", "chocolate_bowl", "sprinkles_bowl"} <= set(
        feeding.objects
    )
    assert [p.name for p in feeding.spec.places] == ["mouth"]


def test_goal_set_of_a_layout_moves_the_grasp() -> None:
    sc = load_scene("desk")
    base = sc.goal_set()
    layout = sc.default_layout()
    mug = layout["white_mug"]
    moved = sc.goal_set({"white_mug": type(mug)(mug.x + 0.05, mug.y, mug.yaw)})
    i = base.index("white_mug")
    np.testing.assert_allclose(moved.positions[i] - base.positions[i], [0.05, 0, 0], atol=1e-12)
    np.testing.assert_allclose(np.delete(moved.positions, i, 0), np.delete(base.positions, i, 0))


def test_unknown_and_fixed_names_are_rejected_with_the_known_ones() -> None:
    sc = load_scene("desk")
    with pytest.raises(InputError, match="white_mug"):
        sc.goal_set(goals=["teapot", "white_mug"])
    with pytest.raises(InputError, match="fixed"):
        LayoutConstraints.of(sc, ["tape_dispenser", "white_mug"])
    with pytest.raises(InputError, match=r"known: .*desk"):
        load_scene("no_such_scene")


@pytest.mark.parametrize("name", ["a\nb", "desk\u2028x", "x\rdesk", "de\x85sk", "\x0c", "a\x1eb"])
def test_an_unknown_name_with_a_line_break_stays_on_one_line(name: str) -> None:
    # a remote load_scene command carries any string (found by the command fuzzing)
    with pytest.raises(InputError) as info:
        load_scene(name)
    assert len(str(info.value).splitlines()) == 1, str(info.value)
