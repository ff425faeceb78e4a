"""The arm's meshes in MuJoCo's binary format: the same model as from the OBJ files, array
for array, and only OBJ files of the simple form converted."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from legws_daemon.robot import assets, world
from legws_daemon.robot.mesh_files import fast_mesh_path, obj_to_msh

#: What MuJoCo derives from a mesh: compared between the OBJ and the binary file.
FIELDS = (
    "mesh_vert", "mesh_normal", "mesh_texcoord", "mesh_face", "mesh_facenormal",
    "mesh_facetexcoord", "mesh_pos", "mesh_quat", "mesh_vertnum", "body_mass",
    "body_inertia", "body_ipos", "body_iquat", "geom_size", "geom_rbound", "geom_aabb",
)  # fmt: skip


def _assert_same_model(a: mujoco.MjModel, b: mujoco.MjModel) -> None:
    for field in FIELDS:
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)


def _box_obj(normals: bool = True, tex: bool = True, corner: str = "{0}/{0}/{0}") -> str:
    """A unit box as robosuite's exporter writes meshes: one index for v, vt and vn."""
    rng = np.random.default_rng(3)
    verts = [(x, y, z) for x in (0.0, 1.0) for y in (0.0, 0.5) for z in (0.0, 0.25)]
    tris = [(0, 2, 1), (1, 2, 3), (4, 5, 6), (5, 7, 6), (0, 1, 4), (1, 5, 4),
            (2, 6, 3), (3, 6, 7), (0, 4, 2), (2, 4, 6), (1, 3, 5), (3, 7, 5)]  # fmt: skip
    lines = ["# exported", "mtllib a.mtl", "o box", "usemtl grey", "s 1"]
    for v in verts:
        lines.append("v " + " ".join(f"{c:.6f}" for c in v))
        if normals:
            n = np.asarray(v) - 0.5 + 0.01 * rng.standard_normal(3)
            lines.append("vn " + " ".join(f"{c:.6f}" for c in n / np.linalg.norm(n)))
        if tex:
            lines.append(f"vt {rng.uniform():.6f} {rng.uniform():.6f}")
    for t in tris:
        lines.append("f " + " ".join(corner.format(i + 1) for i in t))
    return "\n".join(lines) + "\n"


def _compiled(mesh_file: Path) -> mujoco.MjModel:
    xml = f"""<mujoco><asset><mesh name="m" file="{mesh_file}"/></asset>
      <worldbody><body><freejoint/><geom type="mesh" mesh="m" density="800"/></body>
      </worldbody></mujoco>"""
    return mujoco.MjModel.from_xml_string(xml)


@pytest.mark.parametrize(
    ("normals", "tex", "corner"),
    [(True, True, "{0}/{0}/{0}"), (True, False, "{0}//{0}"), (False, True, "{0}/{0}"),
     (False, False, "{0}")],
    ids=["v/vt/vn", "v//vn", "v/vt", "v"],
)  # fmt: skip
def test_a_converted_mesh_compiles_to_the_same_model(
    tmp_path: Path, normals: bool, tex: bool, corner: str
) -> None:
    obj = tmp_path / "box.obj"
    obj.write_text(_box_obj(normals, tex, corner))
    msh = obj_to_msh(obj.read_bytes())
    assert msh is not None
    counts = np.frombuffer(msh[:16], dtype=np.int32)
    assert counts.tolist() == [8, 8 if normals else 0, 8 if tex else 0, 12]
    (tmp_path / "box.msh").write_bytes(msh)
    _assert_same_model(_compiled(obj), _compiled(tmp_path / "box.msh"))


NOT_SIMPLE = {
    "a quad": lambda t: t.replace("f 1/1/1 3/3/3 2/2/2", "f 1/1/1 3/3/3 4/4/4 2/2/2"),
    "indices that differ": lambda t: t.replace("f 1/1/1 3/3/3 2/2/2", "f 1/2/1 3/3/3 2/2/2"),
    "a negative index": lambda t: t.replace("f 1/1/1 3/3/3 2/2/2", "f -8/-8/-8 3/3/3 2/2/2"),
    "an index past the end": lambda t: t.replace("f 1/1/1 3/3/3 2/2/2", "f 9/9/9 3/3/3 2/2/2"),
    "a normal missing": lambda t: t.replace("vn ", "# vn ", 1),
    "a record it does not know": lambda t: t + "l 1 2\n",
    "a coordinate that is not a number": lambda t: t.replace("v 0.000000", "v zero", 1),
    "a NaN coordinate": lambda t: t.replace("v 0.000000", "v nan", 1),
    "not ASCII": lambda t: t + "# caf\u00e9\n",
    "no faces": lambda t: "\n".join(x for x in t.splitlines() if not x.startswith("f ")),
}


@pytest.mark.parametrize("damage", NOT_SIMPLE.values(), ids=NOT_SIMPLE.keys())
def test_an_obj_not_of_the_simple_form_stays_an_obj(damage: object) -> None:
    text = _box_obj()
    changed = damage(text)  # type: ignore[operator]
    assert changed != text
    assert obj_to_msh(changed.encode()) is None


def test_the_arm_loads_the_binary_meshes_and_compiles_to_the_same_model(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    model = assets.verify()
    fast = {rel: model.fast_mesh(rel) for rel in model.sha256 if rel.endswith(".obj")}
    loaded = {m.file for m in world._robot_spec(world.resolve_arm("sawyer"), visual=True).meshes}
    assert loaded and all(f.startswith("fast_meshes/") for f in loaded), loaded
    assert loaded <= {f for f in fast.values() if f}
    with_fast = world.robot_model()
    monkeypatch.setattr(assets.Verified, "fast_mesh", lambda self, rel: None)
    assert all(
        m.file.endswith(".obj")
        for m in world._robot_spec(world.resolve_arm("sawyer"), visual=True).meshes
    )
    _assert_same_model(with_fast, world.robot_model())


def test_a_fast_mesh_is_named_after_its_objs_content() -> None:
    model = assets.verify()
    for rel, digest in model.sha256.items():
        if model.fast_mesh(rel) is not None:
            assert model.fast_mesh(rel) == fast_mesh_path(digest)
            assert (model.folder / fast_mesh_path(digest)).is_file()
