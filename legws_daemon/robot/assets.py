"""The arms' robot descriptions, fetched once with pip at set-up and cached on disk.

The MJCF and meshes come from robosuite's wheel on PyPI (MIT licence), which ships a
standalone ``robots/<arm>`` folder per arm (Sawyer, Panda, UR5e, Kinova Gen3, ...: the
folder each :class:`~legws_daemon.arms.ArmSpec` names). robosuite itself is never
installed (it pins an old mink): the wheel is downloaded with ``pip download --no-deps``
and only the registered arms' folders are unpacked into the asset cache, one folder per arm
(``<cache>/<arm name>``). Nothing is downloaded at run time.

Integrity: the fetch writes a manifest into the folder's marker ``legws-asset.json`` (every
file's relative path, size and sha256, and one digest over them all). Every
:func:`arm_dir` checks the folder against it, because this model also drives the real
arm's kinematics: a missing, changed, truncated or replaced file is one ``InputError``
naming the file and the command that restores the folder. Hashing the ~55 MB folder takes
~0.15 s; the result is kept per process for each file's (path, size, mtime, ctime, inode),
so later calls only ``lstat`` the files (~1 ms) and a changed file is hashed again.

The fetch also writes each mesh that ``robot.xml`` loads in MuJoCo's binary format (see
:mod:`legws_daemon.robot.mesh_files`: the same model, compiled ~0.3 s sooner), listed in
the manifest like the rest.

Cache location: ``$LEGWS_ASSETS``, else ``.assets/`` in a source checkout, else
``~/.cache/legws/assets``.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
import stat
import subprocess
import sys
import tempfile
import threading
import xml.etree.ElementTree as ET
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

from legws_daemon.arms import DEFAULT_ARM, ArmSpec, arm, arm_names
from legws_daemon.errors import InputError, LegwsError
from legws_daemon.formats.nesting import check_json_nesting
from legws_daemon.robot.mesh_files import FAST_MESH_DIR, fast_mesh_path, obj_to_msh

ROBOSUITE_VERSION = "1.5.2"
_ROBOTS = "robosuite/models/assets/robots/"
_MARKER = "legws-asset.json"
FETCH_COMMAND = "./dev setup   (or: legws assets fetch)"
#: What restores a damaged model: download it again and replace the folder atomically.
RESTORE_COMMAND = "legws assets fetch --force"
MANIFEST_VERSION = 1
#: Bytes read at a time when hashing, and the largest marker file read at all.
_CHUNK = 1 << 20
_MAX_MARKER = 1 << 20


@dataclass(frozen=True, slots=True)
class ManifestEntry:
    path: str  # relative, POSIX separators
    size: int
    sha256: str


@dataclass(frozen=True, slots=True)
class Verified:
    """A model folder that matched its manifest."""

    folder: Path
    files: int
    size: int
    digest: str  # sha256 over the manifest's entries: one name for the whole model
    sha256: Mapping[str, str]  # each listed file's sha256, by relative path

    def fast_mesh(self, rel: str) -> str | None:
        """The binary mesh the manifest lists for the OBJ ``rel`` as it is now, else None."""
        digest = self.sha256.get(rel)
        fast = fast_mesh_path(digest) if digest else None
        return fast if fast in self.sha256 else None


def assets_dir() -> Path:
    env = os.environ.get("LEGWS_ASSETS")
    if env:
        return Path(env)
    repo = Path(__file__).resolve().parents[2]
    if (repo / "pyproject.toml").is_file():
        return repo / ".assets"
    return Path.home() / ".cache" / "legws" / "assets"


def arm_dir(root: Path | None = None, name: str = DEFAULT_ARM) -> Path:
    """Folder holding the arm's ``robot.xml`` and its meshes, checked against the fetch's
    manifest.

    Raises:
        InputError: one line saying which command fetches the model when it is missing, or
            which file is damaged and which command restores it.
    """
    return verify(root, name).folder


def model_digest(root: Path | None = None, name: str = DEFAULT_ARM) -> str:
    """The verified model's overall sha256 (e.g. for cache keys that depend on the robot)."""
    return verify(root, name).digest


def description_digest(spec: ArmSpec) -> str:
    """The overall sha256 of an arm's model: its verified folder's, or its inline MJCF's."""
    if spec.model_xml is not None:
        return hashlib.sha256(spec.model_xml.encode()).hexdigest()
    return model_digest(None, spec.name)


def arm_key(spec: ArmSpec) -> str:
    """sha256 of an arm's model files and its whole description (what a map, a plan or a
    run made for the arm depends on)."""
    h = hashlib.sha256(description_digest(spec).encode())
    h.update(json.dumps(spec.facts(), sort_keys=True).encode())
    return h.hexdigest()


def _spec(name: str) -> ArmSpec:
    try:
        return arm(name)
    except KeyError as err:
        raise InputError(str(err.args[0])) from None


# --- hashing ------------------------------------------------------------------------------
class _DamagedError(Exception):
    """One file of the model does not match: how, and which sub-folder when it is that."""

    def __init__(self, how: str, what: str | None = None) -> None:
        super().__init__(how)
        self.how = how
        self.what = what


def _hash_file(path: Path, expected_size: int) -> str:
    """sha256 of a regular file of ``expected_size`` bytes, read in bounded chunks.

    Refuses a symlink (``O_NOFOLLOW``), a device, a FIFO or a folder (checked on the open
    descriptor, so a swap between check and open is caught) and never reads more than
    ``expected_size + 1`` bytes.
    """
    flags = os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
    try:
        fd = os.open(path, flags)
    except OSError as err:
        if err.errno == errno.ELOOP:
            raise _DamagedError("is a symlink, expected a regular file") from None
        raise _DamagedError(f"cannot be read ({err.strerror or err})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise _DamagedError("is not a regular file")
        h = hashlib.sha256()
        remaining = expected_size + 1  # one byte more shows a file that grew meanwhile
        while remaining > 0:
            try:
                block = os.read(fd, min(_CHUNK, remaining))
            except OSError as err:
                raise _DamagedError(f"cannot be read ({err.strerror or err})") from None
            if not block:
                break
            h.update(block)
            remaining -= len(block)
        if remaining != 1:
            raise _DamagedError("changed size while it was read")
        return h.hexdigest()
    finally:
        os.close(fd)


def _overall_digest(entries: list[ManifestEntry]) -> str:
    """The model's name: sha256 over the shipped files' entries. The binary meshes derived
    from them are left out (each is still checked against its own entry): they are the
    same model, and the caches keyed by it (the shipped reachability map) stay valid."""
    h = hashlib.sha256()
    shipped = (e for e in entries if not e.path.startswith(f"{FAST_MESH_DIR}/"))
    for e in sorted(shipped, key=lambda e: e.path):
        h.update(f"{e.path}\0{e.size}\0{e.sha256}\n".encode())
    return h.hexdigest()


# --- the manifest -------------------------------------------------------------------------
def _clean_relpath(text: object) -> str | None:
    """``text`` as a safe relative POSIX path inside the folder, else None."""
    if not isinstance(text, str) or not text or "\\" in text:
        return None
    if any(ord(c) < 32 or ord(c) == 127 for c in text):
        return None
    p = PurePosixPath(text)
    if p.is_absolute() or any(part in ("", ".", "..") for part in text.split("/")):
        return None
    return str(p)


def _parse_manifest(raw: object) -> tuple[list[ManifestEntry], str]:
    """Entries and overall digest of a marker's ``manifest``; ValueError names the flaw."""
    if not isinstance(raw, dict):
        raise ValueError(
            "has no manifest (written by an older legws: nothing to check the files against)"
        )
    if raw.get("version") != MANIFEST_VERSION or raw.get("algorithm") != "sha256":
        raise ValueError(
            f"has a manifest that is not version {MANIFEST_VERSION} with sha256 "
            "(written by another legws, or edited)"
        )
    files = raw.get("files")
    if not isinstance(files, list) or not files:
        raise ValueError("has a manifest that lists no files")
    entries: list[ManifestEntry] = []
    seen: set[str] = set()
    for item in files:
        if not isinstance(item, dict):
            raise ValueError("has a manifest entry that is not an object")
        path = _clean_relpath(item.get("path"))
        size, digest = item.get("size"), item.get("sha256")
        if (
            path is None
            or path in seen
            or path == _MARKER
            or type(size) is not int
            or size < 0
            or not isinstance(digest, str)
            or len(digest) != 64
            or any(c not in "0123456789abcdef" for c in digest)
        ):
            raise ValueError("has a malformed manifest entry (path, size or sha256)")
        seen.add(path)
        entries.append(ManifestEntry(path, size, digest))
    if "robot.xml" not in seen:
        raise ValueError("has a manifest that does not list robot.xml")
    overall = raw.get("digest")
    if overall != _overall_digest(entries):
        raise ValueError("has a manifest whose digest does not match its entries (edited)")
    return entries, overall


def _read_marker(marker: Path, st: os.stat_result) -> dict[str, Any]:
    """The marker's JSON object; ValueError says why not (bounded read, regular file)."""
    if not stat.S_ISREG(st.st_mode):
        raise ValueError("is not a regular file")
    if st.st_size > _MAX_MARKER:
        raise ValueError(f"is larger than {_MAX_MARKER} bytes")
    try:
        with marker.open("rb") as f:
            data = f.read(_MAX_MARKER + 1)
        text = data.decode("utf-8")
        check_json_nesting(text, str(marker))
        obj = json.loads(text)
    except InputError as err:
        raise ValueError(f"is not a manifest: {err}") from None
    except OSError as err:
        raise ValueError(f"cannot be read ({err.strerror or err})") from None
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError):
        raise ValueError("is not valid JSON") from None
    if not isinstance(obj, dict):
        raise ValueError("is not a JSON object")
    return obj


# --- verification, cached per process -----------------------------------------------------
_StatKey = tuple[str, int, int, int, int, int]
#: sha256 of files already hashed, and parsed manifests, keyed on (path, size, mtime_ns,
#: ctime_ns, inode, device): a file written, replaced or touched since has another key and
#: is read again.
_HASHED: dict[_StatKey, str] = {}
_MANIFESTS: dict[_StatKey, tuple[list[ManifestEntry], str]] = {}
_CACHE_MAX = 4096
_LOCK = threading.Lock()


def _stat_key(path: str, st: os.stat_result) -> _StatKey:
    return (path, st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino, st.st_dev)


def _remember(cache: dict[_StatKey, Any], key: _StatKey, value: Any) -> None:
    if len(cache) >= _CACHE_MAX:
        cache.clear()
    cache[key] = value


def _damaged(folder: Path, what: str, how: str, title: str) -> InputError:
    return InputError(
        f"the {title} model is damaged: {folder / what} {how}; restore it with: {RESTORE_COMMAND}"
    )


def _lstat(path: str) -> os.stat_result:
    try:
        return os.lstat(path)
    except FileNotFoundError:
        raise _DamagedError("is missing") from None
    except OSError as err:
        raise _DamagedError(f"cannot be read ({err.strerror or err})") from None


def _check_entry(folder: str, entry: ManifestEntry, dirs_ok: set[str]) -> None:
    """Raise ``_DamagedError`` unless the file of ``entry`` matches it.

    ``dirs_ok``: sub-folders already found to be real folders (not symlinks) in this check.
    """
    # no symlink anywhere below the folder: a link to elsewhere certifies nothing here
    parts = entry.path.split("/")
    sub = folder
    for i, part in enumerate(parts[:-1]):
        sub = f"{sub}/{part}"
        if sub not in dirs_ok:
            rel = "/".join(parts[: i + 1])
            try:
                mode = _lstat(sub).st_mode
            except _DamagedError as err:
                raise _DamagedError(err.how, rel) from None
            if stat.S_ISLNK(mode):
                raise _DamagedError("is a symlink, expected a folder", rel)
            if not stat.S_ISDIR(mode):
                raise _DamagedError("is not a folder", rel)
            dirs_ok.add(sub)
    path = f"{sub}/{parts[-1]}"
    st = _lstat(path)
    if stat.S_ISLNK(st.st_mode):
        raise _DamagedError("is a symlink, expected a regular file")
    if not stat.S_ISREG(st.st_mode):
        raise _DamagedError("is not a regular file")
    if st.st_size != entry.size:
        raise _DamagedError(f"has {st.st_size} bytes, the fetch's manifest says {entry.size}")
    key = _stat_key(path, st)
    digest = _HASHED.get(key)
    if digest is None:
        digest = _hash_file(Path(path), entry.size)
        _remember(_HASHED, key, digest)
    if digest != entry.sha256:
        raise _DamagedError("differs from the fetch's manifest (sha256)")


def _manifest(marker: Path) -> tuple[list[ManifestEntry], str]:
    """The marker's manifest, parsed once per version of the file; ValueError if bad."""
    try:
        st = os.lstat(marker)
    except OSError as err:
        raise ValueError(f"cannot be read ({err.strerror or err})") from None
    key = _stat_key(str(marker), st)
    cached = _MANIFESTS.get(key)
    if cached is None:
        cached = _parse_manifest(_read_marker(marker, st).get("manifest"))
        _remember(_MANIFESTS, key, cached)
    return cached


def verify(root: Path | None = None, name: str = DEFAULT_ARM) -> Verified:
    """Check the arm's folder against its manifest (see the module's docstring).

    Raises:
        InputError: one line: not fetched (and how to fetch), or the damaged file and
            ``legws assets fetch --force``.
    """
    title = _spec(name).title
    folder = (root or assets_dir()) / name
    marker = folder / _MARKER
    if not folder.is_dir() or not (marker.exists() or marker.is_symlink()):
        if folder.is_dir() and any(folder.iterdir()):
            raise _damaged(folder, _MARKER, "is missing (the fetch did not complete)", title)
        raise InputError(
            f"the {title} model is not fetched (looked in {folder}); fetch it with: {FETCH_COMMAND}"
        )
    with _LOCK:
        try:
            entries, overall = _manifest(marker)
        except ValueError as err:
            raise _damaged(folder, _MARKER, str(err), title) from None
        dirs_ok: set[str] = set()
        for entry in entries:
            try:
                _check_entry(str(folder), entry, dirs_ok)
            except _DamagedError as err:
                raise _damaged(folder, err.what or entry.path, err.how, title) from None
    return Verified(
        folder, len(entries), sum(e.size for e in entries), overall,
        {e.path: e.sha256 for e in entries},
    )  # fmt: skip


def _model_meshes(folder: Path) -> list[str]:
    """The OBJ files ``robot.xml`` loads, relative to the folder (none if it names a mesh
    or asset folder, or cannot be parsed: then nothing is converted and MuJoCo reads the
    model as shipped)."""
    try:
        root = ET.parse(folder / "robot.xml").getroot()
    except (OSError, ET.ParseError):
        return []
    if any("meshdir" in c.attrib or "assetdir" in c.attrib for c in root.iter("compiler")):
        return []
    files = {m.get("file", "") for m in root.iter("mesh")}
    return sorted(f for f in files if f.lower().endswith(".obj") and _clean_relpath(f) == f)


def _write_fast_meshes(folder: Path) -> int:
    """Convert the model's OBJ meshes to MuJoCo's binary format beside them; how many."""
    written = 0
    for rel in _model_meshes(folder):
        path = folder / rel
        if not path.is_file() or path.is_symlink():
            continue
        data = path.read_bytes()
        msh = obj_to_msh(data)
        if msh is None:
            continue
        out = folder / fast_mesh_path(hashlib.sha256(data).hexdigest())
        out.parent.mkdir(exist_ok=True)
        out.write_bytes(msh)
        written += 1
    return written


def _write_manifest(folder: Path, source: dict[str, Any]) -> None:
    """Hash every file below ``folder`` and write the marker with its manifest.

    Only for a folder just unpacked by :func:`fetch` (hashing content of unknown origin
    certifies nothing).
    """
    entries: list[ManifestEntry] = []
    for dirpath, dirnames, filenames in os.walk(folder):
        dirnames.sort()
        for name in sorted(filenames):
            path = Path(dirpath) / name
            rel = path.relative_to(folder).as_posix()
            if rel == _MARKER:
                continue
            st = path.lstat()
            if not stat.S_ISREG(st.st_mode):
                raise LegwsError(f"the fetched model folder holds a non-regular file: {rel}")
            entries.append(ManifestEntry(rel, st.st_size, _hash_file(path, st.st_size)))
    manifest = {
        "version": MANIFEST_VERSION,
        "algorithm": "sha256",
        "digest": _overall_digest(entries),
        "files": [{"path": e.path, "size": e.size, "sha256": e.sha256} for e in entries],
    }
    (folder / _MARKER).write_text(json.dumps({**source, "manifest": manifest}, indent=1))


def fetch(
    root: Path | None = None, *, force: bool = False, names: tuple[str, ...] | None = None
) -> dict[str, Path]:
    """Download robosuite's wheel with pip and unpack the arms' folders into the cache.

    ``names``: the arms (default: every registered one). Without ``force``, an intact cached
    model is kept (and nothing is downloaded when all are). Atomic per arm: the new folder
    is unpacked and hashed beside the cache, then swapped in with two renames; the old one
    is removed after. Returns each arm's verified folder.
    """
    root = root or assets_dir()
    wanted = tuple(names or arm_names())
    todo: list[ArmSpec] = []
    for name in wanted:
        spec = _spec(name)
        if not force:
            try:
                arm_dir(root, name)
                continue
            except InputError:
                pass
        todo.append(spec)
    if not todo:
        return {n: arm_dir(root, n) for n in wanted}
    root.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=root, prefix=".fetch-") as tmp:
        cmd = [
            sys.executable, "-m", "pip", "download", "--no-deps", "--quiet",
            "--disable-pip-version-check", f"robosuite=={ROBOSUITE_VERSION}", "-d", tmp,
        ]  # fmt: skip
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        wheels = list(Path(tmp).glob("robosuite-*.whl"))
        if proc.returncode != 0 or not wheels:
            last = (proc.stderr.strip().splitlines() or ["no wheel downloaded"])[-1]
            raise LegwsError(f"pip download of robosuite=={ROBOSUITE_VERSION} failed: {last}")
        with zipfile.ZipFile(wheels[0]) as wheel:
            for spec in todo:
                _unpack(wheel, spec, root, Path(tmp))
    return {n: arm_dir(root, n) for n in wanted}


def _unpack(wheel: zipfile.ZipFile, spec: ArmSpec, root: Path, tmp: Path) -> None:
    """Unpack one arm's folder of the wheel, hash it, and swap it into ``root/<name>``."""
    prefix = f"{_ROBOTS}{spec.asset_folder}/"
    staging = tmp / spec.name
    members = [n for n in wheel.namelist() if n.startswith(prefix) and not n.endswith("/")]
    if not any(n == prefix + "robot.xml" for n in members):
        raise LegwsError(
            f"robosuite=={ROBOSUITE_VERSION} has no {spec.asset_folder}/robot.xml "
            f"(the model of arm {spec.name})"
        )
    for name in members:
        rel = _clean_relpath(name[len(prefix) :])
        if rel is None or rel == _MARKER:
            raise LegwsError(f"robosuite's wheel holds an unsafe file name: {name!r}")
        dest = staging / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        with wheel.open(name) as src, dest.open("wb") as out:
            shutil.copyfileobj(src, out, _CHUNK)
    converted = _write_fast_meshes(staging)
    _write_manifest(
        staging,
        {"source": f"robosuite=={ROBOSUITE_VERSION}", "arm": spec.name,
         "files": len(members) + converted},
    )  # fmt: skip
    target = root / spec.name
    if target.exists() or target.is_symlink():
        target.rename(tmp / f"old-{spec.name}")  # removed with the temporary folder
    staging.rename(target)
