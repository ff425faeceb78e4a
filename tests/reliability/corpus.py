"""A generated corpus of hostile inputs for every ``legws`` command and the daemon's loaders.

Every kind of file legws reads (scene, layout, goal set, task graph, plan, hardware
profile, input mapping, zenoh configuration, joystick log, optimiser elites, recording)
is written from a valid document and then broken: truncated, emptied, garbage, not UTF-8,
nested too deeply, a key given twice, a byte-order mark, over its size limit, NUL bytes;
a field given the wrong type, an extreme or non-finite number, a name with terminal
escapes, bidirectional controls, NUL or a carriage return; an unknown key. It is also
replaced by what is not a regular file: a FIFO (which would block a reader), a socket, a
character device, a link to ``/dev/zero`` (which never ends), a folder, nothing, a
dangling link. Every output option is pointed at the same non-files and at a file where a
folder is expected. Numeric options get the extremes that break the maths.

Every case must end within 5 s with exit 2 and ``legws: error:`` lines only, one per error
(a broken field is one line; a document with several wrong fields, or a wrong field and
the required one it stood for, has a line for each, every one ``FILE:LINE: field: ...``
when the field is in the file), stay under 1 GiB, and change no file outside its output
path (:func:`snapshot`).
"""

from __future__ import annotations

import copy
import hashlib
import json
import os
import random
import socket
import stat
import tomllib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from legws_daemon.formats.files import LIMITS
from tests.cli.helpers import EXAMPLE_GOALSET
from tests.formats.helpers import toml_dumps
from tests.reliability.classes import (
    PATH_CASES,
    depth_texts,
    image_cases,
    key_path_texts,
    place_path,
    size_texts,
)

REPO = Path(__file__).parents[2]


@dataclass(frozen=True)
class Case:
    """One command line against the sandbox (paths relative to the sandbox's root)."""

    name: str
    argv: list[str]
    env: dict[str, str] = field(default_factory=dict)

    def to_json(self, root: Path) -> dict[str, Any]:
        return {"argv": self.argv, "cwd": str(root), "env": self.env}


# --- the valid documents --------------------------------------------------------------------


def _layout_doc() -> dict[str, Any]:
    from legws_daemon.scene.catalog import load_scene
    from legws_daemon.scene.layout_file import layout_to_data

    scene = load_scene("desk")
    return layout_to_data(scene.default_layout())


def _plan_doc() -> dict[str, Any]:
    from legws_daemon.task.plan_file import plan_to_data
    from tests.task.test_plan_file import feeding_plan

    return plan_to_data(feeding_plan())


def _joystick_lines() -> list[dict[str, Any]]:
    return [
        {
            "schema": 1,
            "seq": i,
            "stamp": 1000.0 + 0.05 * i,
            "axes": [0.1, 0.0, 0.0],
            "buttons": {"enable": True},
            "source": "corpus",
        }
        for i in range(5)
    ]


def _zenoh_doc() -> dict[str, Any]:
    return {
        "mode": "peer",
        "listen": {"endpoints": ["tcp/127.0.0.1:1"]},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
    }


def _elites_doc() -> list[dict[str, Any]]:
    return [{"rank": 0, "layout": _layout_doc(), "objective": 0.5, "verified": True}]


@dataclass(frozen=True)
class Kind:
    """A kind of file: its valid document, format, file name, and the commands reading it
    (``{f}``: the file; ``{d}``: its folder)."""

    name: str
    limit: str  # the size-limit kind of :data:`LIMITS`
    fmt: str  # "json", "toml", "jsonl", "json5", "bytes"
    doc: Callable[[], Any]
    commands: list[list[str]]
    filename: str = "file"
    #: changes that leave this kind valid (a goal set may carry extra fields: interfaces.md)
    valid_changes: tuple[str, ...] = ()

    def text(self, doc: Any) -> bytes:
        if self.fmt == "toml":
            return toml_dumps(doc).encode()
        if self.fmt == "jsonl":
            first, *rest = doc
            return "\n".join(json.dumps(d, allow_nan=True) for d in (first, *rest)).encode() + b"\n"
        return json.dumps(doc, allow_nan=True, indent=1).encode()


def _toml_file(path: str) -> Callable[[], Any]:
    return lambda: tomllib.loads((REPO / path).read_text())


P = "{profile}"  # the sandbox's sim profile (a free loopback port, scouting off)
DAEMON = ["daemon", "--profile", P, "--duration", "3"]
KINDS: list[Kind] = [
    Kind(
        "scene",
        "scene",
        "toml",
        _toml_file("scenes/desk.toml"),
        [
            ["certify", "--scene", "{f}", "--json"],
            [*DAEMON, "--scene", "{f}"],
            ["render", "--scene", "{f}", "-o", "out/scene.png"],
            ["eval", "--scene", "{f}", "--layouts", "random:1", "--quiet", "--workers", "1"],
            ["optimize", "--scene", "{f}", "--iterations", "1", "--quiet", "--out", "out/opt"],
        ],
        "scene.toml",
    ),
    Kind(
        "layout",
        "layout",
        "json",
        _layout_doc,
        [
            ["certify", "--scene", "desk", "--layout", "{f}", "--json"],
            [*DAEMON, "--scene", "desk", "--layout", "{f}"],
            ["render", "--scene", "desk", "--layout", "{f}", "-o", "out/layout.png"],
            ["eval", "--scene", "desk", "--layouts", "{f}", "--quiet", "--workers", "1"],
        ],
        "layout.json",
    ),
    Kind(
        "goal set",
        "goal set",
        "json",
        lambda: copy.deepcopy(EXAMPLE_GOALSET),
        [
            ["certify", "{f}", "--json"],
            ["certify", "{f}", "--commit"],
            ["certify", "{f}", "--monte-carlo", "10"],
        ],
        "goals.json",
        ("unknown-key",),
    ),
    Kind(
        "task graph",
        "task graph",
        "toml",
        _toml_file("taskgraphs/tea.toml"),
        [
            ["taskgraph", "check", "{f}"],
            ["taskgraph", "show", "{f}"],
            [*DAEMON, "--taskgraph", "{f}"],
            ["plan", "{f}", "--quiet", "--no-cache"],
        ],
        "tea.toml",
    ),
    Kind(
        "plan",
        "plan",
        "json",
        _plan_doc,
        [
            [*DAEMON, "--taskgraph", "feeding", "--plan", "{d}"],
            [*DAEMON, "--taskgraph", "feeding", "--plan", "{f}"],
        ],
        "plan.json",
    ),
    Kind(
        "hardware profile",
        "hardware profile",
        "toml",
        _toml_file("hw_profiles/sim.toml"),
        [
            ["daemon", "--profile", "{f}", "--scene", "desk", "--duration", "3"],
            ["joystick", "sim-user", "--profile", "{f}", "--duration", "1"],
            ["bridge", "fake", "--profile", "{f}"],
        ],
        "profile.toml",
    ),
    Kind(
        "input mapping",
        "input mapping",
        "toml",
        _toml_file("hw_profiles/input/xbox.toml"),
        [
            ["joystick", "evdev", "--profile", P, "--mapping", "{f}", "--device", "in/no-device"],
        ],
        "mapping.toml",
    ),
    Kind(
        "zenoh config",
        "zenoh config",
        "json5",
        _zenoh_doc,
        [
            [*DAEMON, "--scene", "desk", "--zenoh-config", "{f}"],
            ["secure", "check", "{f}"],
            ["joystick", "sim-user", "--profile", P, "--zenoh-config", "{f}", "--duration", "1"],
        ],
        "zenoh.json5",
        ("byte-order-mark",),
    ),
    Kind(
        "joystick log",
        "joystick log",
        "jsonl",
        _joystick_lines,
        [
            ["joystick", "replay", "{f}", "--profile", P, "--duration", "1"],
        ],
        "session.jsonl",
    ),
    Kind(
        "elites",
        "elites",
        "json",
        _elites_doc,
        [
            ["eval", "--scene", "desk", "--layouts", "{d}", "--quiet", "--workers", "1"],
        ],
        "elites.json",
        ("unknown-key",),
    ),
    Kind(
        "recording",
        "recording",
        "bytes",
        lambda: None,
        [
            ["recording", "finish", "{f}"],
            ["replay", "{f}"],
        ],
        "session.rrd",
    ),
]


# --- breaking a document ----------------------------------------------------------------------


def _leaves(doc: Any, here: tuple[Any, ...] = ()) -> Iterator[tuple[tuple[Any, ...], Any]]:
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _leaves(v, (*here, k))
    elif isinstance(doc, list) and doc:
        for i, v in enumerate(doc):
            yield from _leaves(v, (*here, i))
    else:
        yield here, doc


def _set(doc: Any, path: tuple[Any, ...], value: Any) -> Any:
    doc = copy.deepcopy(doc)
    if not path:
        return value
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    parent[path[-1]] = value
    return doc


def _first(doc: Any, want: type | tuple[type, ...]) -> tuple[Any, ...] | None:
    for path, value in _leaves(doc):
        if isinstance(value, want) and not isinstance(value, bool):
            return path
    return None


def _on_string(value: str) -> Callable[[Any], Any | None]:
    def change(doc: Any) -> Any | None:
        path = _first(doc, str)
        return None if path is None else _set(doc, path, value)

    return change


def _on_number(value: Any) -> Callable[[Any], Any | None]:
    def change(doc: Any) -> Any | None:
        path = _first(doc, (int, float))
        return None if path is None else _set(doc, path, value)

    return change


def _extra_key(doc: Any) -> Any | None:
    if isinstance(doc, dict):
        return {**doc, "zz_unknown_key": 1}
    if isinstance(doc, list) and doc and isinstance(doc[0], dict):
        return [{**doc[0], "zz_unknown_key": 1}, *doc[1:]]
    return None


def _wrong_type(doc: Any) -> Any | None:
    path = _first(doc, (int, float, str))
    return None if path is None else _set(doc, path, {"nested": [1, 2]})


#: Changes to the document: each makes it invalid for every kind.
DOC_CHANGES: dict[str, Callable[[Any], Any | None]] = {
    "esc-in-name": _on_string("\x1b[2J\x1b[31mred"),
    "bidi-in-name": _on_string("abc\u202edcba"),
    "nul-in-name": _on_string("a\x00b"),
    "cr-in-name": _on_string("fine\rEVIL"),
    "huge-number": _on_number(1e308),
    "negative-huge-number": _on_number(-1e308),
    "nan": _on_number(float("nan")),
    "infinity": _on_number(float("inf")),
    "wrong-type": _wrong_type,
    "unknown-key": _extra_key,
    "top-level-list": lambda doc: [doc] if isinstance(doc, dict) else None,
    "top-level-string": lambda doc: "just a string" if not isinstance(doc, list) else None,
}


def _duplicate_key(kind: Kind, text: bytes) -> bytes | None:
    """The document with its first key given twice (JSON) or its first line twice (TOML)."""
    if kind.fmt in ("json", "json5"):
        body = text.lstrip()
        if not body.startswith(b"{"):
            return None
        key = json.loads(text).__iter__().__next__()
        return b'{"' + key.encode() + b'": 0,' + body[1:]
    if kind.fmt == "jsonl":
        first, _, rest = text.partition(b"\n")
        return b'{"seq": 0,' + first[1:] + b"\n" + rest
    if kind.fmt == "toml":
        first = next(line for line in text.splitlines() if b"=" in line)
        return first + b"\n" + text
    return None


#: Changes to the written bytes.
TEXT_CHANGES: dict[str, Callable[[Kind, bytes], bytes | None]] = {
    "empty": lambda k, t: b"",
    "truncated": lambda k, t: t[: len(t) // 2],
    "garbage": lambda k, t: random.Random(len(t)).randbytes(4096),
    "not-utf8": lambda k, t: t.replace(b'"', b'"\xff\xfe', 1) if b'"' in t else b"\xff" + t,
    "nested-deeply": lambda k, t: (b"a = " if k.fmt == "toml" else b"") + b"[" * 200_000,
    "duplicate-key": _duplicate_key,
    "byte-order-mark": lambda k, t: b"\xef\xbb\xbf" + t,
    "nul-bytes": lambda k, t: b"\0" * 1000,
    "long-line": lambda k, t: b"x" * 200_000,
}

#: What is not a regular file, in place of an input.
SPECIALS = [
    "fifo",
    "socket",
    "char-device",
    "link-to-dev-zero",
    "folder",
    "missing",
    "dangling-link",
    "link-to-fifo",
]


# --- the sandbox ------------------------------------------------------------------------------


class Sandbox:
    """A folder holding the inputs (``in/``), special files (``special/``), outputs (``out/``,
    the only place a case may write) and the caches (``cache/``)."""

    def __init__(self, root: Path, port: int) -> None:
        self.root = root
        for sub in ("in", "special", "out", "cache"):
            (root / sub).mkdir(parents=True, exist_ok=True)
        text = (REPO / "hw_profiles" / "sim.toml").read_text()
        self.profile = root / "in" / "sim.toml"
        self.profile.write_text(text.replace("tcp/127.0.0.1:7447", f"tcp/127.0.0.1:{port}"))
        self.env = {
            "XDG_CACHE_HOME": str(root / "cache"),
            "MESA_SHADER_CACHE_DIR": str(root / "out" / "mesa"),
            "CI": "true",
        }
        self._count = 0

    def _new(self, kind: Kind, label: str) -> Path:
        self._count += 1
        folder = self.root / "in" / f"{self._count:04d}-{kind.name.replace(' ', '_')}-{label}"
        folder.mkdir()
        return folder / kind.filename

    def folder(self, kind: Kind, label: str) -> Path:
        """A new folder of its own for a case."""
        return self._new(kind, label).parent

    def file(self, kind: Kind, label: str, data: bytes) -> Path:
        path = self._new(kind, label)
        path.write_bytes(data)
        return path

    def oversized(self, kind: Kind) -> Path:
        path = self._new(kind, "over-the-size-limit")
        with path.open("wb") as f:
            f.truncate(LIMITS[kind.limit] + 1)  # sparse: a size, nothing to read
        return path

    def special(self, kind: Kind, what: str) -> Path:
        path = self._new(kind, what)
        make_special(path, what, self.root / "special")
        return path

    def argv(self, template: list[str], path: Path) -> list[str]:
        rel = path.relative_to(self.root)
        return [
            a.replace("{f}", str(rel))
            .replace("{d}", str(rel.parent))
            .replace("{profile}", str(self.profile.relative_to(self.root)))
            for a in template
        ]


def make_special(path: Path, what: str, spare: Path) -> None:
    """Put ``what`` at ``path``: a FIFO, a socket, a character device (a private copy of
    /dev/null's numbers: if anything wrote over it, only this node would be harmed)..."""
    if what == "fifo":
        os.mkfifo(path)
    elif what == "socket":
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        here = os.getcwd()
        try:
            os.chdir(path.parent)  # a socket's path has a short length limit: bind by name
            sock.bind(path.name)
        finally:
            os.chdir(here)
            sock.close()
    elif what == "char-device":
        try:
            os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, 3))
        except PermissionError:
            path.symlink_to("/dev/null")  # not root: a link to the real one (never written)
    elif what == "link-to-dev-zero":
        path.symlink_to("/dev/zero")
    elif what == "folder":
        path.mkdir()
    elif what == "missing":
        pass
    elif what == "dangling-link":
        path.symlink_to(spare / f"nothing-{path.parent.name}-{path.name}")
    elif what == "link-to-fifo":
        target = spare / f"fifo-{path.parent.name}-{path.name}"
        os.mkfifo(target)
        path.symlink_to(target)
    else:
        raise ValueError(what)


# --- the cases --------------------------------------------------------------------------------


def file_cases(box: Sandbox, kind: Kind) -> list[Case]:
    """Every broken file of ``kind``, each through one of its commands (in turn), and every
    special file through all of them."""
    cases: list[Case] = []
    turn = 0

    def add(label: str, path: Path, every: bool = False) -> None:
        nonlocal turn
        templates = kind.commands if every else [kind.commands[turn % len(kind.commands)]]
        turn += 1
        for t in templates:
            cases.append(Case(f"{kind.name}/{label}/{t[0]}", box.argv(t, path), box.env))

    if kind.fmt != "bytes":
        doc = kind.doc()
        valid = kind.text(doc)
        for label, change in DOC_CHANGES.items():
            if label in kind.valid_changes:
                continue
            broken = change(doc)
            if broken is not None and broken != doc:
                add(label, box.file(kind, label, kind.text(broken)))
        for label, text_change in TEXT_CHANGES.items():
            if label in kind.valid_changes:
                continue
            data = text_change(kind, valid)
            if data is not None:
                add(label, box.file(kind, label, data))
        for texts in (depth_texts(kind), key_path_texts(kind), size_texts(kind, valid)):
            for label, data in texts:
                add(label, box.file(kind, label, data))
        add("over-the-size-limit", box.oversized(kind))
    else:
        for label, data in {
            "empty": b"",
            "garbage": random.Random(1).randbytes(4096),
            "nul-bytes": b"\0" * 4096,
            "text": b"not a recording\n",
        }.items():
            add(label, box.file(kind, label, data), every=True)
    for what in SPECIALS:
        add(what, box.special(kind, what), every=True)
    for what in PATH_CASES:
        folder = box.folder(kind, what)
        path = place_path(box.root, folder, kind.filename, what, b"{}")
        if path is not None:  # a name too long for the system: through every command
            add(what, path, every=what == "name-too-long")
    return cases


def parameter_cases(box: Sandbox) -> list[Case]:
    """Goal-set parameters and command-line options at extremes that break the maths."""
    goal_params = {
        "alpha-1e-17": ("alpha", 1e-17),
        "alpha-0": ("alpha", 0.0),
        "alpha-1": ("alpha", 1.0),
        "beta-tiny": ("beta", 1e-300),
        "beta-huge": ("beta", 1e300),
        "beta-0": ("beta", 0.0),
        "sigma-tiny": ("sigma", 1e-300),
        "sigma-huge": ("sigma", 1e300),
        "sigma-negative": ("sigma", -0.03),
        "dt-tiny": ("dt", 1e-300),
        "v-max-0": ("v_max", 0.0),
        "horizon-2": ("horizon_fraction", 2.0),
        "rotation-weight-huge": ("rotation_weight", 1e300),
    }
    kind = KINDS[2]
    cases = []
    for label, (key, value) in goal_params.items():
        doc = copy.deepcopy(EXAMPLE_GOALSET)
        doc["params"][key] = value
        path = box.file(kind, label, kind.text(doc))
        for extra in (["--json"], []):
            cases.append(
                Case(
                    f"params/{label}{'/json' if extra else ''}",
                    box.argv(["certify", "{f}", *extra], path),
                    box.env,
                )
            )
    many = copy.deepcopy(EXAMPLE_GOALSET)
    many["goals"] = [
        {
            "name": f"g{i}",
            "position": [0.4 + (i % 100) * 0.004, -0.4 + (i // 100) * 0.004, 0.05],
            "quaternion": [0, 1, 0, 0],
        }
        for i in range(20_000)
    ]
    path = box.file(kind, "twenty-thousand-goals", kind.text(many))
    cases.append(Case("params/20000-goals", box.argv(["certify", "{f}", "--json"], path), box.env))
    many["goals"] = many["goals"][:2000]
    path = box.file(kind, "two-thousand-goals", kind.text(many))
    cases.append(Case("params/2000-goals", box.argv(["certify", "{f}", "--json"], path), box.env))
    far = tomllib.loads((REPO / "scenes" / "desk.toml").read_text())
    for label, change in {
        "object-100m": lambda d: d["objects"][0].__setitem__("size", [100.0, 100.0]),
        "object-1km-away": lambda d: d["objects"][0].__setitem__("position", [1000.0, 0.0]),
        "table-100m": lambda d: d["workspace"].__setitem__("table_size", [100.0, 100.0]),
    }.items():
        doc = copy.deepcopy(far)
        change(doc)
        path = box.file(KINDS[0], label, toml_dumps(doc).encode())
        cases.append(
            Case(
                f"params/{label}", box.argv(["certify", "--scene", "{f}", "--json"], path), box.env
            )
        )
    g = "in/goals-valid.json"
    (box.root / g).write_text(json.dumps(EXAMPLE_GOALSET))
    d = ["daemon", "--profile", str(box.profile.relative_to(box.root)), "--scene", "desk"]
    u = ["joystick", "sim-user", "--profile", str(box.profile.relative_to(box.root))]
    options = {
        "monte-carlo-huge": ["certify", g, "--monte-carlo", "10000000"],
        "monte-carlo-0": ["certify", g, "--monte-carlo", "0"],
        "monte-carlo-negative": ["certify", g, "--monte-carlo", "-5"],
        "monte-carlo-text": ["certify", g, "--monte-carlo", "many"],
        "daemon-rate-0": [*d, "--rate", "0"],
        "daemon-rate-nan": [*d, "--rate", "nan"],
        "daemon-rate-huge": [*d, "--rate", "1e9"],
        "daemon-duration-negative": [*d, "--duration", "-1"],
        "daemon-duration-inf": [*d, "--duration", "inf"],
        "sim-user-sigma-nan": [*u, "--sigma", "nan"],
        "sim-user-sigma-huge": [*u, "--sigma", "1e300"],
        "sim-user-rate-inf": [*u, "--rate", "inf"],
        "replay-beta-0": ["replay", "in/no.rrd", "--beta", "0"],
        "replay-threshold-2": ["replay", "in/no.rrd", "--threshold", "2"],
        "secure-port-99999": ["secure", "init", "out/secure-a", "--port", "99999"],
        "secure-listen-99999": ["secure", "init", "out/secure-b", "--listen", "tcp/0.0.0.0:99999"],
        "secure-host-escape": ["secure", "init", "out/secure-c", "--host", "a\x1b[2Jb"],
        "bridge-listen-99999": ["bridge", "fake", "--listen", "tcp/127.0.0.1:99999"],
        "bridge-connect-port-0": ["bridge", "fake", "--connect", "tcp/127.0.0.1:0"],
        "eval-random-0": ["eval", "--scene", "desk", "--layouts", "random:0", "--quiet"],
        "eval-random-huge": ["eval", "--scene", "desk", "--layouts", "random:99999999"],
        "optimize-iterations-0": ["optimize", "--scene", "desk", "--iterations", "0"],
        "optimize-dask-nothing": [
            "optimize",
            "--all",
            "--scene",
            "desk",
            "--dask",
            "tcp://127.0.0.1:1",
            "--iterations",
            "1",
        ],
        "optimize-dask-not-an-address": [
            "optimize",
            "--all",
            "--scene",
            "desk",
            "--dask",
            "nowhere at all",
        ],
        "render-width-0": ["render", "--scene", "desk", "--width", "0", "-o", "out/w.png"],
        "taskgraph-unknown": ["taskgraph", "check", "no_such_graph"],
        "taskgraph-escape-name": ["taskgraph", "check", "tea\x1b[2J"],
        "scene-escape-name": ["certify", "--scene", "desk\u202e", "--json"],
        "joystick-replay-speed-0": ["joystick", "replay", "in/none.jsonl", "--speed", "0"],
        "recording-timeout-nan": ["recording", "finish", "in/no.rrd", "--timeout", "nan"],
        "placement-plan-name-too-long": ["placement", "feeding", "--plan", "in/" + "n" * 300],
    }
    cases += [Case(f"options/{k}", v, box.env) for k, v in options.items()]
    cases += [Case(f"images/{k}", v, box.env) for k, v in image_cases(box.root)]
    return cases


#: Options that write a file, and those that write a folder (``{t}``: the target).
FILE_OUTPUTS = {
    "certify-export-goals": ["certify", "--scene", "desk", "--export-goals", "{t}"],
    "render-output": ["render", "--scene", "desk", "-o", "{t}"],
    "taskgraph-show-png": ["taskgraph", "show", "tea", "--png", "{t}"],
    "daemon-trace": [*DAEMON, "--scene", "desk", "--trace", "{t}"],
    "daemon-rerun-save": [*DAEMON, "--scene", "desk", "--rerun", "save:{t}"],
    "sim-user-record": [
        "joystick",
        "sim-user",
        "--profile",
        P,
        "--record",
        "{t}",
        "--duration",
        "1",
    ],
}
FOLDER_OUTPUTS = {
    "eval-out": [
        "eval",
        "--scene",
        "desk",
        "--layouts",
        "random:1",
        "--out",
        "{t}",
        "--quiet",
        "--workers",
        "1",
    ],
    "optimize-out": [
        "optimize",
        "--scene",
        "desk",
        "--iterations",
        "1",
        "--out",
        "{t}",
        "--quiet",
    ],
    "optimize-all-out": [
        "optimize",
        "--all",
        "--scene",
        "desk",
        "--iterations",
        "1",
        "--out",
        "{t}",
        "--quiet",
        "--workers",
        "1",
    ],
    "plan-out": ["plan", "tea", "--out", "{t}", "--quiet"],
    "demo-out": ["demo", "tea", "--out", "{t}"],
    "secure-init": ["secure", "init", "{t}"],
}
FILE_TARGETS = [
    "fifo",
    "socket",
    "char-device",
    "link-to-char-device",
    "link-to-fifo",
    "folder",
    "missing-folder",
]
FOLDER_TARGETS = ["fifo", "socket", "char-device", "link-to-char-device", "regular-file"]


#: Options whose file's folder is made when missing (documented): not a hostile target.
MAKES_FOLDER = {"render-output", "taskgraph-show-png"}


def output_cases(box: Sandbox) -> list[Case]:
    """Every output option pointed at what it must not write over. The targets live in
    ``special/``, outside ``out/``: none of them may change."""
    cases = []
    spare = box.root / "special"
    n = 0
    for outputs, targets in ((FILE_OUTPUTS, FILE_TARGETS), (FOLDER_OUTPUTS, FOLDER_TARGETS)):
        for name, template in outputs.items():
            for target in targets:
                if target == "missing-folder" and name in MAKES_FOLDER:
                    continue
                n += 1
                path = spare / f"t{n:03d}-{target}"
                if target == "link-to-char-device":
                    make_special(spare / f"t{n:03d}-node", "char-device", spare)
                    path.symlink_to(spare / f"t{n:03d}-node")
                elif target == "regular-file":
                    path.write_text("a file where a folder is expected\n")
                elif target == "missing-folder":
                    path = spare / f"t{n:03d}-no-such-folder" / "out.file"
                else:
                    make_special(path, target, spare)
                rel = str(path.relative_to(box.root))
                argv = [
                    a.replace("{t}", rel).replace(
                        "{profile}", str(box.profile.relative_to(box.root))
                    )
                    for a in template
                ]
                cases.append(Case(f"output/{name}/{target}", argv, box.env))
    return cases


def all_cases(box: Sandbox, group: str) -> list[Case]:
    if group == "parameters":
        return parameter_cases(box)
    if group == "outputs":
        return output_cases(box)
    kind = next(k for k in KINDS if k.name.replace(" ", "_") == group)
    return file_cases(box, kind)


GROUPS = [k.name.replace(" ", "_") for k in KINDS] + ["parameters", "outputs"]


# --- nothing else changes ---------------------------------------------------------------------


def snapshot(root: Path, skip: tuple[str, ...] = ("out", ".runner")) -> dict[str, tuple[Any, ...]]:
    """Every entry below ``root`` (except ``skip``): type, inode, size, mode, and the sha256
    of a regular file's bytes. Special files are only ``lstat``-ed, never opened."""
    out: dict[str, tuple[Any, ...]] = {}
    for dirpath, dirnames, filenames in os.walk(root):
        rel = Path(dirpath).relative_to(root)
        if rel.parts and rel.parts[0] in skip:
            dirnames[:] = []
            continue
        for name in [*dirnames, *filenames]:
            if not rel.parts and name in skip:
                continue
            p = Path(dirpath) / name
            st = os.lstat(p)
            digest = ""
            if stat.S_ISREG(st.st_mode) and st.st_blocks:  # sparse files: size only
                digest = hashlib.sha256(p.read_bytes()).hexdigest()
            key = str(p.relative_to(root))
            out[key] = (
                stat.S_IFMT(st.st_mode),
                st.st_ino,
                st.st_size,
                st.st_mode,
                digest,
                os.readlink(p) if stat.S_ISLNK(st.st_mode) else None,
            )
    return out
