"""Integrity of the cached Sawyer model: the fetch's manifest, the check on every load, and
one line (never a traceback) naming the damaged file and ``legws assets fetch --force``.

Every test works on a copy of the asset cache in a temporary folder (``LEGWS_ASSETS``
points at it): the real cache is only read.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import zipfile
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from legws_daemon.cli.main import run
from legws_daemon.errors import InputError, LegwsError
from legws_daemon.robot import assets
from legws_daemon.robot.mesh_files import fast_mesh_path
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene
from tests.cli.helpers import Result, assert_bad_input

RESTORE = "legws assets fetch --force"
MESH = "obj_meshes/l4/l4_7.obj"  # a mesh robot.xml loads


@pytest.fixture
def model(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A copy of the intact Sawyer folder; ``LEGWS_ASSETS`` points at its root."""
    source = assets.arm_dir()  # the real cache, read only
    root = tmp_path / "assets"
    shutil.copytree(source, root / "sawyer", symlinks=True)
    monkeypatch.setenv("LEGWS_ASSETS", str(root))
    return root / "sawyer"


@pytest.fixture
def hash_calls(monkeypatch: pytest.MonkeyPatch) -> list[Path]:
    """The files the check hashes, in order (the real hash still runs)."""
    calls: list[Path] = []
    real = assets._hash_file

    def counting(path: Path, expected_size: int) -> str:
        calls.append(Path(path))
        return real(path, expected_size)

    monkeypatch.setattr(assets, "_hash_file", counting)
    return calls


def _manifest(folder: Path) -> dict[str, Any]:
    manifest: dict[str, Any] = json.loads((folder / "legws-asset.json").read_text())["manifest"]
    return manifest


def _one_line(err: InputError) -> str:
    text = str(err)
    assert "\n" not in text and "\r" not in text, text
    assert RESTORE in text, text
    return text


# --- an intact model ------------------------------------------------------------------------
def test_the_marker_keeps_its_fields_and_lists_every_file(model: Path) -> None:
    marker = json.loads((model / "legws-asset.json").read_text())
    assert marker["source"] == f"robosuite=={assets.ROBOSUITE_VERSION}"
    files = {p.relative_to(model).as_posix() for p in model.rglob("*") if p.is_file()}
    files.discard("legws-asset.json")
    listed = {e["path"]: e for e in marker["manifest"]["files"]}
    assert set(listed) == files
    assert marker["files"] == len(files)
    assert listed["robot.xml"]["size"] == (model / "robot.xml").stat().st_size
    assert len(marker["manifest"]["digest"]) == 64


def test_an_intact_copy_verifies(model: Path) -> None:
    assert assets.arm_dir() == model
    v = assets.verify()
    assert v.files == len(_manifest(model)["files"])
    assert v.digest == _manifest(model)["digest"] == assets.model_digest()


def test_the_check_is_cached_and_a_changed_file_is_hashed_again(
    model: Path, hash_calls: list[Path]
) -> None:
    n = len(_manifest(model)["files"])
    assets.arm_dir()
    assert len(hash_calls) == n  # cold: every file once
    assets.arm_dir()
    assets.model_digest()
    assert len(hash_calls) == n  # cached: nothing read again
    mesh = model / MESH
    st = mesh.stat()
    os.utime(mesh, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))  # touched only
    assets.arm_dir()
    assert hash_calls[n:] == [mesh]  # only the touched file, and it still matches
    data = bytearray(mesh.read_bytes())
    data[len(data) // 2] ^= 0xFF  # same size, one byte changed
    mesh.write_bytes(bytes(data))
    with pytest.raises(InputError) as info:
        assets.arm_dir()
    assert str(mesh) in _one_line(info.value) and "sha256" in str(info.value)


# --- a damaged model ------------------------------------------------------------------------
def _garbage_xml(folder: Path) -> str:
    (folder / "robot.xml").write_bytes(b"\x00\xff not <mujoco> at all")
    return "robot.xml"


def _empty_xml(folder: Path) -> str:
    (folder / "robot.xml").write_bytes(b"")
    return "robot.xml"


def _truncated_mesh(folder: Path) -> str:
    mesh = folder / MESH
    mesh.write_bytes(mesh.read_bytes()[:1000])
    return MESH


def _same_size_mesh(folder: Path) -> str:
    mesh = folder / MESH
    mesh.write_bytes(b"#" * mesh.stat().st_size)
    return MESH


def _truncated_fast_mesh(folder: Path) -> str:
    # the binary copy the arm loads instead of MESH (tests/robot/test_mesh_files.py)
    digest = assets.verify().sha256[MESH]
    rel = fast_mesh_path(digest)
    fast = folder / rel
    fast.write_bytes(fast.read_bytes()[:100])
    return rel


def _deleted_mesh(folder: Path) -> str:
    (folder / MESH).unlink()
    return MESH


def _marker_without_manifest(folder: Path) -> str:
    # what the fetch of an older legws wrote
    (folder / "legws-asset.json").write_text('{"source": "robosuite==1.5.2", "files": 69}')
    return "legws-asset.json"


def _unparsable_marker(folder: Path) -> str:
    marker = folder / "legws-asset.json"
    marker.write_bytes(marker.read_bytes()[:200])
    return "legws-asset.json"


def _edited_manifest(folder: Path) -> str:
    marker = folder / "legws-asset.json"
    data = json.loads(marker.read_text())
    data["manifest"]["files"][0]["size"] += 1
    marker.write_text(json.dumps(data))
    return "legws-asset.json"


def _missing_marker(folder: Path) -> str:
    (folder / "legws-asset.json").unlink()
    return "legws-asset.json"


def _xml_symlink_to_dev_zero(folder: Path) -> str:
    (folder / "robot.xml").unlink()
    (folder / "robot.xml").symlink_to("/dev/zero")
    return "robot.xml"


def _mesh_symlink_to_an_identical_copy(folder: Path) -> str:
    elsewhere = folder.parent.parent / "elsewhere.obj"
    shutil.copyfile(folder / MESH, elsewhere)
    (folder / MESH).unlink()
    (folder / MESH).symlink_to(elsewhere)
    return MESH


def _mesh_folder_symlink(folder: Path) -> str:
    sub = folder / "obj_meshes" / "l4"
    shutil.move(sub, folder.parent.parent / "l4")
    sub.symlink_to(folder.parent.parent / "l4", target_is_directory=True)
    return "obj_meshes/l4"


def _mesh_is_a_fifo(folder: Path) -> str:
    (folder / MESH).unlink()
    os.mkfifo(folder / MESH)  # opening it for reading would block: it is never opened
    return MESH


DAMAGE: dict[str, Callable[[Path], str]] = {
    "garbage robot.xml": _garbage_xml,
    "empty robot.xml": _empty_xml,
    "truncated mesh": _truncated_mesh,
    "same-size garbage mesh": _same_size_mesh,
    "deleted mesh": _deleted_mesh,
    "truncated binary mesh": _truncated_fast_mesh,
    "marker without manifest": _marker_without_manifest,
    "unparsable marker": _unparsable_marker,
    "edited manifest": _edited_manifest,
    "missing marker": _missing_marker,
    "robot.xml -> /dev/zero": _xml_symlink_to_dev_zero,
    "mesh -> identical copy elsewhere": _mesh_symlink_to_an_identical_copy,
    "mesh folder -> elsewhere": _mesh_folder_symlink,
    "mesh is a FIFO": _mesh_is_a_fifo,
}


@pytest.mark.parametrize("damage", DAMAGE.values(), ids=DAMAGE.keys())
def test_a_damaged_model_is_one_line_naming_the_file_and_the_restore_command(
    model: Path, damage: Callable[[Path], str]
) -> None:
    what = damage(model)
    with pytest.raises(InputError) as info:
        assets.arm_dir()
    line = _one_line(info.value)
    assert str(model / what) in line, line
    assert "damaged" in line
    with pytest.raises(InputError) as info:  # what every command builds on
        World(load_scene("desk"), visual=False)
    assert str(info.value) == line


def test_a_model_found_intact_is_checked_again(model: Path) -> None:
    assets.arm_dir()  # found intact, and cached
    what = _truncated_mesh(model)
    with pytest.raises(InputError) as info:
        assets.arm_dir()
    line = _one_line(info.value)
    assert f"{model / what} has 1000 bytes, the fetch's manifest says" in line


# --- the CLI: exit 2 and one line on stderr -------------------------------------------------
def _cli(capfd: pytest.CaptureFixture[str], *argv: str | Path) -> Result:
    capfd.readouterr()
    code = run([str(a) for a in argv])
    out, err = capfd.readouterr()
    return Result(code, out, err)


@pytest.mark.parametrize(
    "damage", [_garbage_xml, _truncated_mesh, _marker_without_manifest, _xml_symlink_to_dev_zero]
)
def test_render_of_a_damaged_model_exits_2_with_one_line(
    model: Path,
    tmp_path: Path,
    capfd: pytest.CaptureFixture[str],
    damage: Callable[[Path], str],
) -> None:
    what = damage(model)
    png = tmp_path / "x.png"
    result = _cli(capfd, "render", "--scene", "desk", "-o", png)
    assert_bad_input(result, str(model / what), RESTORE)
    assert not png.exists()


def test_assets_check_and_status(model: Path, capfd: pytest.CaptureFixture[str]) -> None:
    one = ("--robot", "sawyer")  # the copy holds the Sawyer's model only
    ok = _cli(capfd, "assets", "check", *one)
    assert ok.code == 0, ok
    assert ok.out.startswith(f"{model}: intact") and ok.out.count("\n") == 1
    assert ok.err == ""
    # every arm is checked without --robot: the others are not in the copy
    assert_bad_input(_cli(capfd, "assets", "check"), "Kinova Gen3 model is not fetched")
    _deleted_mesh(model)
    assert_bad_input(_cli(capfd, "assets", "check", *one), str(model / MESH), "missing", RESTORE)
    assert_bad_input(_cli(capfd, "assets", "status", *one), str(model / MESH), RESTORE)


# --- a model that passes the hash but MuJoCo refuses: still one line --------------------------
def _recertify(folder: Path) -> None:
    """Write a manifest for the folder as it is now (what a fetch of bad content would do)."""
    marker = json.loads((folder / "legws-asset.json").read_text())
    del marker["manifest"]
    assets._write_manifest(folder, marker)
    assets.arm_dir()  # passes


@pytest.mark.parametrize(
    ("damage", "visual"),
    [(_garbage_xml, False), (_empty_xml, False), (_same_size_mesh, True)],
    ids=["garbage robot.xml", "empty robot.xml", "garbage mesh"],
)
def test_mujoco_refusing_the_model_is_one_input_error(
    model: Path, damage: Callable[[Path], str], visual: bool
) -> None:
    damage(model)
    _recertify(model)
    with pytest.raises(InputError, match="MuJoCo cannot") as info:
        World(load_scene("desk"), visual=visual)
    line = _one_line(info.value)
    assert line.startswith(f"{model / 'robot.xml'}: "), line


# --- the fetch: writes the manifest, replaces a damaged folder ------------------------------
def _fake_pip(
    files: dict[str, bytes], folders: tuple[str, ...] = ("sawyer",)
) -> Callable[..., subprocess.CompletedProcess[str]]:
    """``pip download`` stand-in: writes a wheel holding ``files`` in robosuite's layout,
    in each of the arms' ``folders``."""

    def fake_run(cmd: list[str], **_: object) -> subprocess.CompletedProcess[str]:
        dest = Path(cmd[cmd.index("-d") + 1])
        with zipfile.ZipFile(dest / "robosuite-1.5.2-py3-none-any.whl", "w") as wheel:
            wheel.writestr("robosuite/__init__.py", "")
            for folder in folders:
                for rel, data in files.items():
                    wheel.writestr(f"{assets._ROBOTS}{folder}/{rel}", data)
        return subprocess.CompletedProcess(cmd, 0, "", "")

    return fake_run


def test_fetch_writes_a_manifest_and_restores_a_damaged_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    files = {"robot.xml": b"<mujoco/>", "obj_meshes/a/a.obj": b"v 0 0 0\n" * 10}
    monkeypatch.setattr(assets, "subprocess", SimpleNamespace(run=_fake_pip(files)))
    root = tmp_path / "assets"
    monkeypatch.setenv("LEGWS_ASSETS", str(root))
    folder = assets.fetch(names=("sawyer",))["sawyer"]
    assert folder == root / "sawyer"
    marker = json.loads((folder / "legws-asset.json").read_text())
    assert marker["files"] == 2
    assert sorted(e["path"] for e in marker["manifest"]["files"]) == sorted(files)
    (folder / "obj_meshes/a/a.obj").write_bytes(b"x")
    # the CLI's fetch without --force downloads a damaged model again; --force always does
    for argv in (
        ("assets", "fetch", "--robot", "sawyer"),
        ("assets", "fetch", "--robot", "sawyer", "--force"),
    ):
        result = _cli(capfd, *argv)
        assert result.code == 0, result
        assert result.out == f"{folder}\n"
        assert (folder / "obj_meshes/a/a.obj").read_bytes() == files["obj_meshes/a/a.obj"]
        assert assets.arm_dir() == folder
    assert [p.name for p in root.iterdir()] == ["sawyer"]  # no staging left behind


def test_fetch_writes_the_binary_meshes_robot_xml_loads_and_lists_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    box = (Path(__file__).parent / "data" / "box.obj").read_bytes()
    xml = b"""<mujoco><asset><mesh name="a" file="obj_meshes/a.obj"/>
      <mesh name="q" file="obj_meshes/quad.obj"/></asset><worldbody><body>
      <geom type="mesh" mesh="a"/><geom type="mesh" mesh="q"/></body></worldbody></mujoco>"""
    quad = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nf 1 2 3 4\nf 1 2 5\nf 2 3 5\n"
    files = {"robot.xml": xml, "obj_meshes/a.obj": box, "obj_meshes/quad.obj": quad,
             "obj_meshes/unused.obj": box}  # fmt: skip
    monkeypatch.setattr(assets, "subprocess", SimpleNamespace(run=_fake_pip(files)))
    folder = assets.fetch(tmp_path, names=("sawyer",))["sawyer"]
    marker = json.loads((folder / "legws-asset.json").read_text())
    fast = fast_mesh_path(hashlib.sha256(box).hexdigest())
    listed = sorted(e["path"] for e in marker["manifest"]["files"])
    assert listed == sorted([*files, fast])  # the quad stays an OBJ; unused is not loaded
    assert marker["files"] == len(listed)
    model = assets.verify(tmp_path)
    assert model.fast_mesh("obj_meshes/a.obj") == fast
    assert model.fast_mesh("obj_meshes/quad.obj") is None
    assert (folder / fast).read_bytes() == assets.obj_to_msh(box)
    # the model's name (the caches' key) is that of the shipped files alone
    monkeypatch.setattr(assets, "obj_to_msh", lambda data: None)
    plain = assets.fetch(tmp_path / "plain", names=("sawyer",))["sawyer"]
    assert not (plain / "fast_meshes").exists()
    assert assets.verify(tmp_path / "plain").digest == model.digest


def test_fetch_refuses_a_wheel_with_an_unsafe_file_name(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    files = {"robot.xml": b"<mujoco/>", "../../escape.txt": b"x"}
    monkeypatch.setattr(assets, "subprocess", SimpleNamespace(run=_fake_pip(files)))
    with pytest.raises(LegwsError, match="unsafe file name"):
        assets.fetch(tmp_path, names=("sawyer",))
    assert not (tmp_path / "sawyer").exists()


def test_fetch_unpacks_each_arm_into_its_own_checked_folder_in_one_download(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    files = {"robot.xml": b"<mujoco/>", "meshes/l.stl": b"solid"}
    calls: list[object] = []
    fake = _fake_pip(files, ("sawyer", "panda", "ur5e"))
    monkeypatch.setattr(
        assets, "subprocess", SimpleNamespace(run=lambda *a, **k: calls.append(a) or fake(*a, **k))
    )
    found = assets.fetch(tmp_path, names=("panda", "ur5e"))
    assert sorted(found) == ["panda", "ur5e"] and len(calls) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["panda", "ur5e"]
    assert json.loads((found["panda"] / "legws-asset.json").read_text())["arm"] == "panda"
    # intact folders are kept: nothing downloaded; a damaged one names its arm
    assets.fetch(tmp_path, names=("panda", "ur5e"))
    assert len(calls) == 1
    (found["ur5e"] / "meshes/l.stl").write_bytes(b"x")
    with pytest.raises(InputError, match="the Universal Robots UR5e model is damaged"):
        assets.verify(tmp_path, "ur5e")
    # an arm whose folder the wheel lacks is one error naming it
    with pytest.raises(LegwsError, match=r"kinova3/robot\.xml"):
        assets.fetch(tmp_path, names=("kinova3",))
