"""Every error of a file, each with its line: ``FILE:LINE: field: what was expected``.

The loaders (task graphs, scenes, hardware profiles, input mappings, goal sets, operator
files, layouts, plans, camera calibrations, optimiser elites) report every validation error
of a file, not the first, each at the line of its field; an unknown key close to a known
one says ``did you mean``, and a required key missing beside it names the misspelt one. An
unknown scene or layout object name says ``did you mean`` too.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from legws_daemon.errors import InputError
from legws_daemon.formats.goalset import load_goalset
from legws_daemon.formats.input_mapping import load_mapping, load_mapping_named, mappings_dir
from legws_daemon.formats.operator_file import load_operator
from legws_daemon.formats.positions import SourceText, json_lines, toml_lines
from legws_daemon.formats.profile import load_profile, load_profile_named, profiles_dir
from legws_daemon.formats.scene_file import MARKER_DICTIONARIES, load_scene_spec
from legws_daemon.formats.validation import (
    ManyInputsError,
    error_lines,
    field_path,
    parse_field_path,
)
from legws_daemon.scene.catalog import load_scene, scene_names, scenes_dir
from legws_daemon.scene.layout_file import load_layout
from legws_daemon.sim.evaluate import load_elites
from legws_daemon.task.plan_file import check_plan, load_plan, load_plan_with_lines, plan_to_data
from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph, taskgraphs_dir
from legws_daemon.tracking.calibration import (
    DEFAULT_BOARD,
    Calibration,
    calibration_to_data,
    load_calibration,
)
from legws_daemon.tracking.camera import Intrinsics
from tests.cli.helpers import EXAMPLE_GOALSET
from tests.task.test_plan_file import feeding_plan

TOML = """# a comment [[not]] a header
a = \"\"\"several
[[fake]]
lines\"\"\"
c = 'literal # not a comment'  # a comment
"quoted.key" = [1,
  2, # after the second
  [3,
   4]]
d.e = {g = 1, h = {i = [5]}}

[[t]]
x = 1
[t.sub]
y = 2
[[t.arr]]
z = 3

[[t]]
x = 2
[[t.arr]]
z = 4
[[t.arr]]
w = \"\"\"a\\\"\"\"
b\"\"\"
v = 1
"""


def test_toml_lines_of_keys_tables_and_elements() -> None:
    lines = toml_lines(TOML)
    assert lines[("a",)] == 2
    assert ("fake",) not in lines  # inside a string
    assert lines[("c",)] == 5
    assert lines[("quoted.key",)] == 6
    assert [lines[("quoted.key", i)] for i in range(3)] == [6, 7, 8]
    assert lines[("quoted.key", 2, 1)] == 9
    assert lines[("d", "e", "h", "i", 0)] == 10
    assert lines[("t",)] == lines[("t", 0)] == 12
    assert lines[("t", 0, "sub", "y")] == 15
    assert lines[("t", 0, "arr", 0, "z")] == 17
    assert lines[("t", 1)] == 19
    assert lines[("t", 1, "arr", 0)] == 21
    assert lines[("t", 1, "arr", 1)] == 23
    assert lines[("t", 1, "arr", 1, "w")] == 24
    assert lines[("t", 1, "arr", 1, "v")] == 26  # after a string with an escaped quote


def test_json_lines_of_keys_and_elements() -> None:
    doc = {"x0": {"position": [1, 2, 3]}, "goals": [{"name": "a"}, {"name": 'b"}'}]}
    text = json.dumps(doc, indent=1)
    lines = json_lines(text)
    numbered = text.splitlines()
    for loc in [("x0",), ("x0", "position", 2), ("goals", 1), ("goals", 1, "name")]:
        assert loc in lines
    assert numbered[lines[("goals", 1, "name")] - 1].strip() == '"name": "b\\"}"'
    assert numbered[lines[("x0", "position", 2)] - 1].strip() == "3"


def test_a_missing_key_is_placed_at_its_table_and_a_missing_table_nowhere() -> None:
    where = SourceText(TOML, "toml")
    assert where.line(("t", 1, "nothing", "deeper")) == 19
    assert where.line(("absent",)) is None
    assert where.at("f.toml", ("t", 1, "x")) == "f.toml:20"
    assert where.at("f.toml", ("absent",)) == "f.toml"


@pytest.mark.parametrize(
    "loc", [("goals", 1, "position"), ("stages", 0, "candidates", 2), ("a",), ("m", 0, 1)]
)
def test_a_field_path_reads_back(loc: tuple[int | str, ...]) -> None:
    assert parse_field_path(field_path(loc)) == loc


def _line(text: str, needle: str, after: int = 0) -> int:
    """The 1-based line of the first ``needle`` at or after line ``after``."""
    lines = text.splitlines()
    return next(i + 1 for i in range(after, len(lines)) if needle in lines[i])


def _quoted(text: str, word: str) -> int:
    """The 1-based line of the first ``"word"`` (a JSON key or string)."""
    return _line(text, f'"{word}"')


def _errors(load: Callable[[Path], object], path: Path) -> list[str]:
    """The lines the CLI would print for the error of loading ``path``."""
    with pytest.raises(InputError) as info:
        load(path)
    text = str(info.value)
    assert "\n" not in text  # one line for logs and events: "; " between the errors
    return error_lines(info.value)


def test_a_renamed_key_in_a_task_graph_names_both_keys_with_their_lines(tmp_path: Path) -> None:
    text = (taskgraphs_dir() / "tea.toml").read_text(encoding="utf-8")
    second = _line(text, "[[stages]]", _line(text, "[[stages]]"))  # the second stage
    assert 'action = "place"' in text
    bad = tmp_path / "tea.toml"
    bad.write_text(text.replace('action = "place"', 'acton = "place"', 1), encoding="utf-8")
    typo = _line(text, 'action = "place"')
    assert _errors(load_taskgraph, bad) == [
        f"{bad}:{second}: stages[1].action: Field required (one of 'pick', 'place', 'dip', "
        f"'feed', 'return'); is 'acton' on line {typo} a misspelling of it?",
        f"{bad}:{typo}: stages[1].acton: Extra inputs are not permitted; did you mean 'action'?",
    ]


def test_every_schema_error_of_a_task_graph_in_line_order(tmp_path: Path) -> None:
    text = (taskgraphs_dir() / "tea.toml").read_text(encoding="utf-8")
    edited = (
        text.replace('scene = "tea"', 'scene = "tea"\nrepeat = "twice"', 1)
        .replace('action = "pick"', 'action = "pik"', 1)
        .replace('prompt = "Into the cup"', "prompt = 3", 1)
        .replace('next = ["serve"]', 'nxt = ["serve"]', 1)
    )
    bad = tmp_path / "tea.toml"
    bad.write_text(edited, encoding="utf-8")
    pik = _line(edited, 'action = "pik"')
    assert _errors(load_taskgraph, bad) == [
        f"{bad}:{_line(edited, 'repeat =')}: repeat: Input should be 'once' or 'until_consumed' "
        "(got 'twice')",
        f"{bad}:{pik}: stages[0].action: Input should be 'pick', "
        "'place', 'dip', 'feed' or 'return' (got 'pik'; did you mean 'pick'?)",
        f"{bad}:{_line(edited, 'prompt = 3')}: stages[1].prompt: Input should be a valid string "
        "(got 3)",
        f"{bad}:{_line(edited, 'nxt =')}: stages[2].nxt: Extra inputs are not permitted; did you "
        "mean 'next'?",
    ]


def test_a_semantic_error_of_a_task_graph_names_its_line(tmp_path: Path) -> None:
    text = (taskgraphs_dir() / "tea.toml").read_text(encoding="utf-8")
    bad = tmp_path / "tea.toml"
    bad.write_text(text.replace('name = "tea"', 'name = "teas"', 1), encoding="utf-8")
    name = _line(text, 'name = "tea"')
    assert _errors(load_taskgraph, bad) == [
        f"{bad}:{name}: name: expected 'tea' (the file's name), got 'teas'"
    ]


def test_an_unknown_task_graph_name_says_did_you_mean() -> None:
    with pytest.raises(InputError) as info:
        resolve_taskgraph("tae")
    assert str(info.value) == (
        "taskgraph: unknown task graph 'tae'; did you mean 'tea'? known: feeding, lego, tea"
    )


def test_every_error_of_a_scene_with_its_line(tmp_path: Path) -> None:
    text = (scenes_dir() / "desk.toml").read_text(encoding="utf-8")
    first = _line(text, "[[objects]]")
    shape = _line(text, "shape =", first)
    grasp = _line(text, "grasp =", _line(text, "[[objects]]", first))  # the second object
    old_shape = text.splitlines()[shape - 1]
    old_grasp = text.splitlines()[grasp - 1]
    edited = text.replace(old_shape, old_shape.replace("shape", "shap"), 1).replace(
        old_grasp, 'grasp = "sid"', 1
    )
    bad = tmp_path / "desk.toml"
    bad.write_text(edited, encoding="utf-8")
    assert _errors(load_scene_spec, bad) == [
        f"{bad}:{first}: objects[0].shape: Field required (one of 'box', 'cylinder', 'sphere'); "
        f"is 'shap' on line {shape} a misspelling of it?",
        f"{bad}:{shape}: objects[0].shap: Extra inputs are not permitted; did you mean 'shape'?",
        f"{bad}:{grasp}: objects[1].grasp: Input should be 'top' or 'side' (got 'sid'; did you "
        "mean 'side'?)",
    ]


def test_every_error_of_a_profile_with_its_line(tmp_path: Path) -> None:
    text = (profiles_dir() / "sim.toml").read_text(encoding="utf-8")
    edited = (
        text.replace('adapter = "sim"', 'adapter = "simm"', 1)
        .replace("rate_hz = 20.0", "rate_hx = 20.0", 1)
        .replace("x = [0.20, 0.95]", "x = [0.95, 0.20]", 1)
    )
    bad = tmp_path / "sim.toml"
    bad.write_text(edited, encoding="utf-8")
    assert _errors(load_profile, bad) == [
        f"{bad}:{_line(edited, 'adapter =')}: adapter: Input should be 'sim', 'bridge' "
        "or 'sawyer' (got 'simm'; did you mean 'sim'?)",
        f"{bad}:{_line(edited, 'rate_hx =')}: control.rate_hx: Extra inputs are not permitted; "
        "did you mean 'rate_hz'?",
        f"{bad}:{_line(edited, 'x = [0.95')}: workspace.x: must be [low, high] with low < high, "
        "got [0.95, 0.2]",
    ]


def test_an_unknown_key_far_from_every_known_one_lists_them(tmp_path: Path) -> None:
    text = (profiles_dir() / "sim.toml").read_text(encoding="utf-8")
    bad = tmp_path / "sim.toml"
    bad.write_text(text.replace("realtime = true", "realtime = true\nwarp = 3", 1), "utf-8")
    assert _errors(load_profile, bad) == [
        f"{bad}:{_line(text, 'realtime = true') + 1}: sim.warp: Extra inputs are not permitted; "
        "known keys: realtime"
    ]


def test_a_profile_name_typo_says_did_you_mean() -> None:
    with pytest.raises(InputError) as info:
        load_profile_named("simm")
    assert str(info.value) == (
        "profile: unknown hardware profile 'simm'; did you mean 'sim'? known: "
        "panda, panda_sim, sawyer, sim"
    )
    with pytest.raises(InputError) as info:
        load_profile_named("moon")
    assert str(info.value) == (
        "profile: unknown hardware profile 'moon'; known: panda, panda_sim, sawyer, sim"
    )


def test_a_profile_file_name_typo_says_did_you_mean(tmp_path: Path) -> None:
    (tmp_path / "bench.toml").write_text((profiles_dir() / "sim.toml").read_text())
    with pytest.raises(InputError) as info:
        load_profile_named(tmp_path / "bnech.toml")
    assert str(info.value) == (
        f"{tmp_path / 'bnech.toml'}: no such file; did you mean '{tmp_path / 'bench.toml'}'?"
    )
    with pytest.raises(InputError) as info:
        load_profile_named(tmp_path / "other.toml")
    assert str(info.value) == f"{tmp_path / 'other.toml'}: no such file"


def test_every_error_of_an_input_mapping_with_its_line(tmp_path: Path) -> None:
    text = (mappings_dir() / "xbox.toml").read_text(encoding="utf-8")
    second = _line(text, "[[axis]]", _line(text, "[[axis]]"))
    deadzone = _line(text, "deadzone =", second)
    drives = _line(text, "drives =", _line(text, "[[axis]]"))
    lines = text.splitlines(keepends=True)
    lines[drives - 1] = 'drives = "w"\n'
    lines[deadzone - 1] = lines[deadzone - 1].replace("deadzone", "deadzon", 1)
    bad = tmp_path / "pad.toml"
    bad.write_text("".join(lines), encoding="utf-8")
    assert _errors(load_mapping, bad) == [
        f"{bad}:{drives}: axis[0].drives: Input should be 'x', 'y', 'z', 'rx', 'ry' or 'rz' "
        "(got 'w')",
        f"{bad}:{deadzone}: axis[1].deadzon: Extra inputs are not permitted; did you mean "
        "'deadzone'?",
    ]
    with pytest.raises(InputError) as info:
        load_mapping_named("xbx")
    assert str(info.value) == (
        "mapping: unknown input mapping 'xbx'; did you mean 'xbox'? known: hid_joystick, "
        "playstation, spacemouse, xbox (or a .toml path)"
    )


def test_every_error_of_a_goal_set_with_its_line(tmp_path: Path) -> None:
    doc = json.loads(json.dumps(EXAMPLE_GOALSET))
    doc["params"]["betta"] = doc["params"].pop("beta")
    doc["goals"][1]["position"][2] = "0.04"
    text = json.dumps(doc, indent=1)
    bad = tmp_path / "goals.json"
    bad.write_text(text, encoding="utf-8")
    z = _line(text, '"0.04"', _line(text, '"stapler"'))
    betta = _line(text, '"betta"')
    assert _errors(load_goalset, bad) == [
        f"{bad}:{z}: goals[1].position[2]: Input should be a valid number (got '0.04')",
        f"{bad}:{betta}: params.betta: Extra inputs are not permitted; did you mean 'beta'?",
    ]


def test_a_goal_set_error_found_after_the_schema_names_its_line(tmp_path: Path) -> None:
    doc = json.loads(json.dumps(EXAMPLE_GOALSET))
    doc["goals"][1]["name"] = "mug"
    text = json.dumps(doc, indent=1)
    bad = tmp_path / "goals.json"
    bad.write_text(text, encoding="utf-8")
    goals = _line(text, '"goals"')
    assert _errors(load_goalset, bad) == [
        f"{bad}:{goals}: goals: goal names must be unique, repeated: mug"
    ]


def test_every_error_of_an_operator_file_with_its_line(tmp_path: Path) -> None:
    doc = {
        "schema": 1, "name": "alice", "speed": 0.92, "sigma": 0.031, "rho": 1.5,
        "bias_deg": -4.1, "steering": "fre", "segments": 20, "ticks": 3120,
        "intervals": {"speed": [0.9, 0.94], "sigma": [0.029, 0.033], "rho": [0.8, 0.86],
                      "bias_deg": [-6.0, -2.2]},
        "certify_with": {"speed": 0.9, "sigma": 0.033, "rho": 0.86, "bias_degs": -6.0,
                         "steering": "free"},
    }  # fmt: skip
    text = json.dumps(doc, indent=2)
    bad = tmp_path / "alice.json"
    bad.write_text(text, encoding="utf-8")
    fre, typo = _line(text, '"fre"'), _line(text, '"bias_degs"')
    table = _line(text, '"certify_with"')
    assert _errors(load_operator, bad) == [
        f"{bad}:{fre}: steering: Input should be 'free', 'axes' or 'axes+diagonals' (got "
        "'fre'; did you mean 'free'?)",
        f"{bad}:{table}: certify_with.bias_deg: Field required; is 'bias_degs' on line {typo} "
        "a misspelling of it?",
        f"{bad}:{typo}: certify_with.bias_degs: Extra inputs are not permitted; did you mean "
        "'bias_deg'?",
    ]


def test_a_control_character_in_toml_names_its_line(tmp_path: Path) -> None:
    text = (taskgraphs_dir() / "tea.toml").read_text(encoding="utf-8")
    bad = tmp_path / "tea.toml"
    bad.write_text(text.replace('"Which tea?"', '"Which \\u001b[2J tea?"', 1), "utf-8")
    assert _errors(load_taskgraph, bad) == [
        f"{bad}:{_line(text, 'Which tea?')}: stages[0].prompt: holds the control character "
        "U+001B; text may not hold control or bidirectional characters"
    ]


def test_every_error_of_a_layout_with_its_line(tmp_path: Path) -> None:
    desk = load_scene("desk")
    assert desk.movable == ("white_mug", "black_stapler", "maroon_pen_cup")
    doc = {
        "white_mug": {"x": 0.45, "y": -0.35, "yw": 0.3},
        "black_stapler": {"x": "0.7", "y": 0.0},
        "maroon_pen_cp": {"x": 0.5, "y": 0.1},
        "tape_dispenser": {"x": 0.6, "y": 0.2},
    }
    text = json.dumps(doc, indent=2)
    bad = tmp_path / "layout.json"
    bad.write_text(text, encoding="utf-8")
    objects = ", ".join(desk.objects)
    assert _errors(lambda p: load_layout(p, desk), bad) == [
        f"{bad}:{_quoted(text, 'yw')}: white_mug.yw: Extra inputs are not permitted; did you "
        "mean 'yaw'?",
        f"{bad}:{_quoted(text, '0.7')}: black_stapler.x: Input should be a valid number "
        "(got '0.7')",
        f"{bad}:{_quoted(text, 'maroon_pen_cp')}: maroon_pen_cp: unknown object "
        f"'maroon_pen_cp' in layout; did you mean 'maroon_pen_cup'? scene 'desk' has: {objects}",
        f"{bad}:{_quoted(text, 'tape_dispenser')}: tape_dispenser: object 'tape_dispenser' is "
        "fixed in scene 'desk'; movable: white_mug, black_stapler, maroon_pen_cup",
    ]


def test_an_unknown_layout_name_far_from_every_object_lists_them(tmp_path: Path) -> None:
    desk = load_scene("desk")
    bad = tmp_path / "layout.json"
    bad.write_text('{\n "white_mug": {"x": 0.45, "y": -0.35},\n "banana": {"x": 0.6, "y": 0}\n}')
    assert _errors(lambda p: load_layout(p, desk), bad) == [
        f"{bad}:3: banana: unknown object 'banana' in layout; scene 'desk' has: "
        + ", ".join(desk.objects)
    ]


def test_every_error_of_an_elites_entry_layout_with_its_line(tmp_path: Path) -> None:
    desk = load_scene("desk")
    layout = {"white_mug": {"x": 0.45, "y": -0.35, "yw": 0.3}, "whte_mug": {"x": 0.5, "y": 0}}
    doc = [{"rank": 0, "layout": layout, "objective": 0.5, "verified": True}]
    text = json.dumps(doc, indent=2)
    (tmp_path / "elites.json").write_text(text, encoding="utf-8")
    path = tmp_path / "elites.json"
    assert _errors(lambda _: load_elites(tmp_path, desk, 1), path) == [
        f"{path}:{_quoted(text, 'yw')}: [0].layout.white_mug.yw: Extra inputs are not "
        "permitted; did you mean 'yaw'?",
        f"{path}:{_quoted(text, 'whte_mug')}: [0].layout.whte_mug: unknown object 'whte_mug' "
        "in layout; scene 'desk' has: " + ", ".join(desk.objects),
    ]
    doc[0]["verified"] = "yes"
    text = json.dumps(doc, indent=2)
    path.write_text(text, encoding="utf-8")
    assert _errors(lambda _: load_elites(tmp_path, desk, 1), path) == [
        f"{path}:{_quoted(text, 'verified')}: [0].verified: Input should be a valid boolean "
        "(got 'yes')"
    ]


def test_every_error_of_a_plan_with_its_line(tmp_path: Path) -> None:
    doc = plan_to_data(feeding_plan())
    first = doc["decisions"][0]
    first["feasable"] = first.pop("feasible")
    doc["decisions"][1]["layout"]["grape"]["x"] = "far"
    text = json.dumps(doc, indent=1)
    bad = tmp_path / "plan.json"
    bad.write_text(text, encoding="utf-8")
    element = _quoted(text, "decisions") + 1  # the line of decisions[0]'s "{"
    assert text.splitlines()[element - 1].strip() == "{"
    typo = _quoted(text, "feasable")
    assert _errors(load_plan, bad) == [
        f"{bad}:{element}: decisions[0].feasible: Field required; is 'feasable' on line {typo} a "
        "misspelling of it?",
        f"{bad}:{typo}: decisions[0].feasable: Extra inputs are not permitted; did you mean "
        "'feasible'?",
        f"{bad}:{_quoted(text, 'far')}: decisions[1].layout.grape.x: Input should be a valid "
        "number (got 'far')",
    ]


def test_a_plan_that_fails_the_checks_names_the_line_of_its_field(tmp_path: Path) -> None:
    text = json.dumps(plan_to_data(feeding_plan()), indent=1)
    path = tmp_path / "plan.json"
    path.write_text(text, encoding="utf-8")
    graph, scene = load_taskgraph(resolve_taskgraph("feeding"))
    plan, where = load_plan_with_lines(path, scene)
    with pytest.raises(InputError) as info:
        check_plan(plan, graph, scene, str(path), where)
    assert error_lines(info.value) == [
        f"{path}:{_quoted(text, 'layout')}: decisions[0].layout: stage 'choose_food': no pose "
        "of the movable object(s) chocolate_bowl, sprinkles_bowl"
    ]
    with pytest.raises(InputError) as info:  # without the text: the file and the field
        check_plan(plan, graph, scene, str(path))
    assert str(info.value).startswith(f"{path}: decisions[0].layout: stage 'choose_food': ")


def _calibration_text(edit: Callable[[dict[str, object]], None]) -> str:
    cal = Calibration(
        Intrinsics.pinhole(50.0, 640, 480), 0.2, 10, (0.2,) * 10, DEFAULT_BOARD,
        "2026-12-02T12:00:00+00:00",
    )  # fmt: skip
    doc = calibration_to_data(cal)
    edit(doc)
    return json.dumps(doc, indent=2)


def test_every_error_of_a_camera_calibration_with_its_line(tmp_path: Path) -> None:
    def edit(doc: dict[str, object]) -> None:
        doc["width"] = 0
        doc["rms_pix"] = doc.pop("rms_px")
        distortion = doc["distortion"]
        assert isinstance(distortion, list)
        distortion[1] = "0"

    text = _calibration_text(edit)
    bad = tmp_path / "calib.json"
    bad.write_text(text, encoding="utf-8")
    typo = _quoted(text, "rms_pix")
    assert _errors(load_calibration, bad) == [
        # a key missing from the top level has no line: first
        f"{bad}: rms_px: Field required; is 'rms_pix' on line {typo} a misspelling of it?",
        f"{bad}:{_quoted(text, 'width')}: width: Input should be greater than or equal to 1 "
        "(got 0)",
        f"{bad}:{_quoted(text, '0')}: distortion[1]: Input should be a valid number (got '0')",
        f"{bad}:{typo}: rms_pix: Extra inputs are not permitted; did you mean 'rms_px'?",
    ]


def test_an_unknown_marker_dictionary_of_a_calibration_says_did_you_mean(tmp_path: Path) -> None:
    def edit(doc: dict[str, object]) -> None:
        board = doc["board"]
        assert isinstance(board, dict)
        board["dictionary"] = "5X5_10"

    text = _calibration_text(edit)
    bad = tmp_path / "calib.json"
    bad.write_text(text, encoding="utf-8")
    assert _errors(load_calibration, bad) == [
        f"{bad}:{_quoted(text, '5X5_10')}: board.dictionary: unknown marker dictionary "
        f"'5X5_10'; did you mean '5X5_100'? known: {', '.join(MARKER_DICTIONARIES)}"
    ]


def test_an_unknown_scene_name_says_did_you_mean() -> None:
    known = ", ".join(scene_names())
    assert "desk" in scene_names()
    with pytest.raises(InputError) as info:
        load_scene("deks")
    assert str(info.value) == f"scene: unknown scene 'deks'; did you mean 'desk'? known: {known}"
    with pytest.raises(InputError) as info:
        load_scene("moon")
    assert str(info.value) == f"scene: unknown scene 'moon'; known: {known}"


def test_a_scene_name_typo_in_a_task_graph_names_its_line_once(tmp_path: Path) -> None:
    text = (taskgraphs_dir() / "tea.toml").read_text(encoding="utf-8")
    bad = tmp_path / "tea.toml"
    bad.write_text(text.replace('scene = "tea"', 'scene = "taa"', 1), encoding="utf-8")
    assert _errors(load_taskgraph, bad) == [
        f"{bad}:{_line(text, 'scene = ')}: scene: unknown scene 'taa'; did you mean 'tea'? known: "
        + ", ".join(scene_names())
    ]


def test_several_errors_are_one_error_with_each_kept() -> None:
    errors = [InputError("a", source="f:1", field="x"), InputError("b", source="f:2", field="y")]
    both = ManyInputsError(errors)
    assert str(both) == "f:1: x: a; f:2: y: b"
    assert error_lines(both) == ["f:1: x: a", "f:2: y: b"]
    assert (both.source, both.field) == ("f:1", "x")
    assert error_lines(errors[0]) == ["f:1: x: a"]
