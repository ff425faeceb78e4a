"""Files: atomic writes that replace only regular files (a link's target), bounded reads
of regular files only, line files that never end in half a line; one-line errors."""

from __future__ import annotations

import contextlib
import json
import os
import socket
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from legws_daemon.errors import InputError
from legws_daemon.formats.files import (
    LIMITS,
    open_output,
    output_folder,
    output_path,
    read_limited,
    write_atomic,
)


def test_replaces_whole_and_leaves_nothing_behind(tmp_path: Path) -> None:
    target = tmp_path / "a.json"
    target.write_text("old")
    write_atomic(target, b"new")
    assert target.read_bytes() == b"new"
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]


def test_missing_folder_is_an_input_error(tmp_path: Path) -> None:
    target = tmp_path / "nope" / "a.json"
    with pytest.raises(InputError, match="cannot write") as info:
        write_atomic(target, b"x")
    assert str(info.value).startswith(str(target))
    assert not (tmp_path / "nope").exists()


# --- what may be written over: regular files, nothing, a link's target --------------------


def special_files(folder: Path) -> dict[str, Path]:
    """A FIFO, a socket, a folder and (as root) a character device, all inside ``folder``:
    if the writer were wrong, only these stand-ins would be harmed, never /dev/null."""
    made = {"FIFO": folder / "fifo", "folder": folder / "dir"}
    os.mkfifo(made["FIFO"])
    made["folder"].mkdir()
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.bind(str(folder / "sock"))
    sock.close()
    made["socket"] = folder / "sock"
    with contextlib.suppress(PermissionError, OSError):
        os.mknod(folder / "null", stat.S_IFCHR | 0o666, os.makedev(1, 3))
        made["character device"] = folder / "null"
    return made


def test_nothing_but_a_regular_file_is_ever_replaced(tmp_path: Path) -> None:
    for kind, path in special_files(tmp_path).items():
        before = os.lstat(path)
        for write in (
            lambda p: write_atomic(p, b"x"),
            lambda p: open_output(p).close(),
            lambda p: output_path(p),
        ):
            with pytest.raises(InputError) as info:
                write(path)
            message = str(info.value)
            assert message.startswith(str(path)) and "\n" not in message
            assert kind in message or (kind == "folder" and "is a folder" in message)
            after = os.lstat(path)
            assert (after.st_mode, after.st_ino) == (before.st_mode, before.st_ino)
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


def test_a_link_is_followed_its_target_replaced_and_the_link_kept(tmp_path: Path) -> None:
    target = tmp_path / "real.json"
    target.write_text("old")
    target.chmod(0o600)
    link = tmp_path / "link.json"
    link.symlink_to(target)
    write_atomic(link, b"new")
    assert link.is_symlink() and target.read_bytes() == b"new"
    assert stat.S_IMODE(target.stat().st_mode) == 0o600  # the file keeps its permissions
    dangling = tmp_path / "dangling.json"
    dangling.symlink_to(tmp_path / "made.json")
    write_atomic(dangling, b"made")
    assert dangling.is_symlink() and (tmp_path / "made.json").read_bytes() == b"made"


def test_a_link_to_a_device_or_fifo_is_refused(tmp_path: Path) -> None:
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    link = tmp_path / "out.json"
    link.symlink_to(fifo)
    with pytest.raises(InputError, match=r"is a FIFO \(a link to .*fifo\); refusing"):
        write_atomic(link, b"x")
    assert link.is_symlink() and stat.S_ISFIFO(os.stat(link).st_mode)
    devnull = tmp_path / "null.png"
    devnull.symlink_to("/dev/null")
    with pytest.raises(InputError, match="character device"):
        write_atomic(devnull, b"x")
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)


def test_output_folder_creates_or_refuses_what_is_in_the_way(tmp_path: Path) -> None:
    made = output_folder(tmp_path / "a" / "b")
    assert made.is_dir()
    assert output_folder(made) == made  # an existing folder is fine
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="is a regular file, expected a folder"):
        output_folder(tmp_path / "file")
    with pytest.raises(InputError, match="cannot create the folder: a file is in the way"):
        output_folder(tmp_path / "file" / "sub")
    os.mkfifo(tmp_path / "fifo")
    with pytest.raises(InputError, match="is a FIFO, expected a folder"):
        output_folder(tmp_path / "fifo")


# --- reading: regular files within a limit ---------------------------------------------------


def test_special_files_are_refused_before_they_are_opened(tmp_path: Path) -> None:
    for kind, path in special_files(tmp_path).items():
        with pytest.raises(InputError) as info:
            read_limited(path, "scene")  # a FIFO would block if it were opened
        assert kind in str(info.value) or kind == "folder"
    link = tmp_path / "zero.json"
    link.symlink_to("/dev/zero")
    with pytest.raises(InputError, match="is a character device, expected a regular file"):
        read_limited(link, "plan")


def test_a_file_over_its_limit_is_refused_before_reading(tmp_path: Path) -> None:
    big = tmp_path / "big.toml"
    with big.open("wb") as f:
        f.truncate(LIMITS["scene"] + 1)  # sparse: nothing to read, only a size
    with pytest.raises(
        InputError, match=r"is 256\.0 KiB, more than the 256 KiB allowed for a scene"
    ):
        read_limited(big, "scene")
    assert len(read_limited(big, "plan")) == LIMITS["scene"] + 1  # a plan may be larger


def test_a_file_that_is_larger_than_it_says_is_cut_at_the_limit(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # /proc files say they are empty and then are not: the reader stops at the limit
    monkeypatch.setitem(LIMITS, "text", 16)
    with pytest.raises(InputError, match="grew beyond the 16 bytes allowed"):
        read_limited(Path("/proc/self/status"), "text")


def test_an_unknown_kind_is_a_programming_error() -> None:
    with pytest.raises(ValueError, match="no size limit"):
        read_limited(Path("/etc/hostname"), "nonsense")


# --- line files: never a partial line ---------------------------------------------------------

_FILL = """
import resource, sys
from legws_daemon.errors import InputError
from legws_daemon.formats.files import open_output
resource.setrlimit(resource.RLIMIT_FSIZE, (1000, 1000))  # a disk that is full at 1000 bytes
out = open_output(sys.argv[1])
pad = "x" * 37
try:
    for i in range(1000):
        out.write(f'{{"line": {i}, "pad": "{pad}"}}\\n')
except InputError as err:
    print(err)
"""


def test_a_full_disk_leaves_whole_lines_and_one_error(tmp_path: Path) -> None:
    path = tmp_path / "trace.jsonl"
    out = subprocess.run(
        [sys.executable, "-c", _FILL, str(path)], capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith(f"{path}: cannot write: File too large"), out.stdout
    text = path.read_text()
    assert 0 < len(text) <= 1000 and text.endswith("\n")
    rows = [json.loads(line) for line in text.splitlines()]
    assert [r["line"] for r in rows] == list(range(len(rows)))
