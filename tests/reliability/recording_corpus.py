"""A generated corpus of hostile daemon recordings (``.rrd``) for ``legws replay`` and
``legws recording finish``, by class, written with the real rerun SDK into real files:

* **docs**: the stage document (``meta/goals`` static and ``meta/stages`` on the timeline,
  as :class:`~legws_daemon.telemetry.rerun_log.RerunLog` logs it) with every field given a
  wrong type, values out of range, a key given twice, negative, huge and non-integer
  format versions, nesting up to 5000 levels, names with terminal escapes, bidirectional
  controls, NUL, line breaks and 100 000 characters, text that is no JSON object;
* **columns**: the EE samples, the text log and the posterior plots with another Arrow
  type, another number of floats in a position, huge and unsigned integers, values out of
  the cell, a ``tick`` timeline of another kind, a row with a terminal escape, a commit
  line with ``p = 5``;
* **damaged**: a raw recording written by the daemon's logger, cut off at several points,
  with 1, 20 and 200 bits flipped at seeded random places, its header overwritten, a
  foreign ``.rrd`` without legws entities, a finished file with a damaged footer;
* **links**: a dangling link, a link to a damaged recording (and, in the test, a link to a
  raw one, which finishes its target).

Every case must end within 5 s with exit 2, exactly one ``legws: error:`` line and nothing
on stdout, under 1 GiB, and leave every file as it was (a recording that cannot be
finished whole is never shrunk). Flipped bits are only a case when rerun's own reader
(``rerun rrd optimize``, not legws) fails on the result: a bit flipped inside an LZ4
literal decodes as other data, which no reader of a format without checksums can tell.
"""

from __future__ import annotations

import copy
import json
import os
import random
import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]
import rerun as rr

from legws_daemon.formats.goalset import goalset_to_data
from legws_daemon.telemetry.rerun_log import (
    EE_ARCHETYPE,
    EE_PATH,
    GOALS_DOC,
    POSTERIOR_PREFIX,
    STAGE_ARCHETYPE,
    STAGES_DOC,
    TELEMETRY_FORMAT,
    TEXT_LOG,
    RerunLog,
)
from legws_daemon.telemetry.rrd_file import rerun_cli, scan
from tests.reliability.corpus import Case
from tests.telemetry.helpers import log_episode, straight_episode

GROUPS = ["docs", "columns", "damaged", "links"]
#: The commands every damaged file goes through.
COMMANDS = (["replay", "{f}"], ["recording", "finish", "{f}"])


class Box:
    """A folder with the inputs (``in/``), the outputs (``out/``: the only place a case may
    write) and the caches."""

    def __init__(self, root: Path) -> None:
        self.root = root
        for sub in ("in", "out", "cache"):
            (root / sub).mkdir(parents=True, exist_ok=True)
        self.env = {"XDG_CACHE_HOME": str(root / "cache"), "CI": "true"}
        self._count = 0

    def path(self, label: str, name: str = "session.rrd") -> Path:
        self._count += 1
        folder = self.root / "in" / f"{self._count:03d}-{label}"
        folder.mkdir()
        return folder / name

    def case(self, name: str, template: list[str], path: Path) -> Case:
        rel = str(path.relative_to(self.root))
        return Case(name, [a.replace("{f}", rel) for a in template], self.env)


# --- the valid pieces -------------------------------------------------------------------------


def valid_doc() -> dict[str, Any]:
    """A stage document as :meth:`RerunLog.log_setup` writes it."""
    ep = straight_episode("breakfast_easy", "banana", hold=1)
    doc = goalset_to_data(ep.goals, ep.params)
    doc.update(
        candidates=list(ep.goals.names),
        inference=True,
        legws_telemetry=TELEMETRY_FORMAT,
        stage="pick",
        robot="sawyer-sim",
        scene=ep.scene.name,
        p_thresh=0.9,
        goal_objects={g: g for g in ep.goals.names},
        planned={"banana": {"x": 0.5, "y": 0.1, "yaw": 0.0}},
        stage_index=0,
    )
    return doc


def ee_components(k: int) -> dict[str, Any]:
    """The EE sample of tick ``k`` (a straight line in front of the robot)."""
    return {
        "position": [0.5 + 0.002 * k, 0.0, 0.3],
        "quaternion": [0.0, 1.0, 0.0, 0.0],
        "t": [0.05 * k],
        "stage": [0],
        "deflection": [1.0, 0.0, 0.0],
        "mode": ["teleop"],
    }


class _Arrow:
    """A ready Arrow array as a component batch (of whatever type it has)."""

    def __init__(self, array: Any) -> None:
        self.array = array

    def as_arrow_array(self) -> Any:
        return self.array


def components(archetype: str, values: dict[str, Any]) -> list[rr.DescribedComponentBatch]:
    """The component batches of one row, each of the Arrow type its values have (rerun's
    own converters would cast them to the type the daemon's logger registered)."""
    return [
        rr.DescribedComponentBatch(
            _Arrow(
                v
                if isinstance(v, pa.Array)
                else pa.array(v if isinstance(v, np.ndarray) else list(v))
            ),
            rr.ComponentDescriptor(f"{archetype}:{name}", archetype=archetype),
        )
        for name, v in values.items()
    ]


def _set_tick(stream: rr.RecordingStream, k: int, kind: str) -> None:
    if kind == "sequence":
        stream.set_time("tick", sequence=k)
    else:
        stream.set_time("tick", duration=float(k))
    stream.set_time("time", duration=0.05 * k)


def write_recording(
    path: Path,
    doc_text: str,
    *,
    ee: Callable[[int], dict[str, Any]] = ee_components,
    ticks: int = 5,
    extra: Callable[[rr.RecordingStream], None] | None = None,
    tick_kind: str = "sequence",
) -> Path:
    """A recording of one stage (its document ``doc_text``) and ``ticks`` EE samples,
    finished by rerun (a footer)."""
    stream = rr.RecordingStream("legws")
    stream.save(path)
    stream.log("meta/robot", rr.TextDocument("sawyer-sim"), static=True)
    stream.log(GOALS_DOC, rr.TextDocument(doc_text), static=True)
    _set_tick(stream, 0, tick_kind)
    stream.log(STAGES_DOC, rr.TextDocument(doc_text))
    for k in range(ticks):
        _set_tick(stream, k, tick_kind)
        stream.log(EE_PATH, components(EE_ARCHETYPE, ee(k)))
    if extra is not None:
        extra(stream)
    stream.disconnect()
    return path


# --- docs ---------------------------------------------------------------------------------------


def _wrong_type(value: Any) -> Any:
    if isinstance(value, bool):
        return "yes"
    if isinstance(value, int | float):
        return str(value)
    if isinstance(value, str):
        return 5
    if isinstance(value, list):
        return {"a": 1}
    if isinstance(value, dict):
        return [1, 2]
    return [None]


def _set(doc: dict[str, Any], where: tuple[Any, ...], value: Any) -> dict[str, Any]:
    out = copy.deepcopy(doc)
    here: Any = out
    for part in where[:-1]:
        here = here[part]
    here[where[-1]] = value
    return out


def _nested(depth: int) -> str:
    return "[" * depth + "]" * depth


def doc_texts() -> dict[str, str]:
    """Hostile stage documents by label, as the text of a ``TextDocument``."""
    doc = valid_doc()
    texts: dict[str, str] = {}

    def put(label: str, d: Any) -> None:
        texts[label] = json.dumps(d)

    for key, value in doc.items():  # every field of the stage doc given a wrong type
        put(f"type-{key}", _set(doc, (key,), _wrong_type(value)))
    for label, where, value in [
        ("type-x0-position", ("x0", "position"), "here"),
        ("type-goal-name", ("goals", 0, "name"), 7),
        ("type-goal-symmetry", ("goals", 0, "symmetry"), 1.5),
        ("type-params-beta", ("params", "beta"), "7"),
        ("type-planned-x", ("planned", "banana", "x"), [0.5]),
        ("type-candidate", ("candidates", 0), 3),
        ("position-two-floats", ("goals", 0, "position"), [0.5, 0.1]),
        ("position-four-floats", ("x0", "position"), [0.5, 0.1, 0.2, 0.3]),
        ("p-thresh-2", ("p_thresh",), 2.0),
        ("p-thresh-0", ("p_thresh",), 0.0),
        ("p-thresh-1", ("p_thresh",), 1.0),
        ("p-thresh-negative", ("p_thresh",), -0.5),
        ("stage-index-negative", ("stage_index",), -1),
        ("stage-index-huge", ("stage_index",), 10**30),
        ("stage-index-float", ("stage_index",), 1.0),
        ("goal-far-away", ("goals", 0, "position"), [1e6, 0.0, 0.0]),
        ("quaternion-zero", ("goals", 1, "quaternion"), [0.0, 0.0, 0.0, 0.0]),
        ("quaternion-huge", ("x0", "quaternion"), [1e300, 1e300, 0.0, 0.0]),
        ("params-beta-negative", ("params", "beta"), -1.0),
        ("params-unknown-key", ("params", "betta"), 1.0),
        ("one-goal", ("goals",), doc["goals"][:1]),
        ("planned-yaw-huge", ("planned", "banana", "yaw"), 1e9),
        ("version-negative", ("legws_telemetry",), -1),
        ("version-zero", ("legws_telemetry",), 0),
        ("version-next", ("legws_telemetry",), TELEMETRY_FORMAT + 1),
        ("version-huge", ("legws_telemetry",), 10**40),
        ("version-text", ("legws_telemetry",), "1"),
        ("version-float", ("legws_telemetry",), 1.0),
        ("version-true", ("legws_telemetry",), True),
        ("stage-escape", ("stage",), "pick\x1b[2J"),
        ("stage-bidi", ("stage",), "pick\u202egnp"),
        ("stage-nul", ("stage",), "pi\x00ck"),
        ("stage-line-break", ("stage",), "pick\nINFO all is well"),
        ("stage-long", ("stage",), "p" * 100_000),
        ("scene-empty", ("scene",), ""),
        ("robot-escape", ("robot",), "\x1b]0;owned\x07"),
        ("goal-object-escape", ("goal_objects", "banana"), "ban\x1b[31mana"),
        ("unknown-key", ("surprise",), 1),
        ("nested-100", ("stage",), json.loads(_nested(100))),
    ]:
        put(label, _set(doc, where, value))
    no_version = copy.deepcopy(doc)
    del no_version["legws_telemetry"]
    put("version-missing", no_version)
    single = _set(doc, ("inference",), False)
    del single["candidates"]
    put("no-inference-no-candidates", single)
    put("no-inference-empty-candidates", _set(single, ("candidates",), []))
    text = json.dumps(doc)
    texts["duplicate-p-thresh"] = text.replace(
        '"p_thresh": 0.9', '"p_thresh": 0.9, "p_thresh": 0.2'
    )
    texts["duplicate-in-goal"] = text.replace('"name": "', '"name": "x", "name": "', 1)
    for depth in (1000, 5000):
        texts[f"nested-{depth}"] = text.replace('"stage": "pick"', f'"stage": {_nested(depth)}')
    texts["nested-object-5000"] = '{"a":' * 5000 + "1" + "}" * 5000
    texts["stage-index-digits"] = text.replace('"stage_index": 0', '"stage_index": ' + "9" * 5000)
    texts["escape-in-key"] = text.replace('"robot"', '"rob\\u001bot"')
    texts["not-json"] = "hello"
    texts["json-list"] = "[1, 2, 3]"
    texts["json-null"] = "null"
    texts["json-string"] = '"legws"'
    texts["nan-p-thresh"] = text.replace('"p_thresh": 0.9', '"p_thresh": NaN')
    texts["empty"] = " "
    for label, t in texts.items():
        assert t != text, label
    return texts


def doc_cases(box: Box) -> list[Case]:
    return [
        box.case(f"docs/{label}", ["replay", "{f}"], write_recording(box.path(label), text))
        for label, text in doc_texts().items()
    ]


# --- columns ------------------------------------------------------------------------------------


def _ee_with(**changes: Any) -> Callable[[int], dict[str, Any]]:
    def ee(k: int) -> dict[str, Any]:
        return {**ee_components(k), **changes}

    return ee


def _text(line: str, *, tick: Any = 4) -> Callable[[rr.RecordingStream], None]:
    def extra(stream: rr.RecordingStream) -> None:
        stream.set_time("tick", sequence=tick)
        stream.log(TEXT_LOG, [*rr.TextLog(line, level="INFO").as_component_batches(),
                              *components(STAGE_ARCHETYPE, {"stage": [0]})])  # fmt: skip

    return extra


def _posterior(value: float) -> Callable[[rr.RecordingStream], None]:
    def extra(stream: rr.RecordingStream) -> None:
        stream.set_time("tick", sequence=2)
        stream.log(POSTERIOR_PREFIX + "banana", rr.Scalars(value))

    return extra


def _sample_at(tick: int) -> Callable[[rr.RecordingStream], None]:
    def extra(stream: rr.RecordingStream) -> None:
        stream.set_time("tick", sequence=tick)
        stream.log(EE_PATH, components(EE_ARCHETYPE, ee_components(1)))

    return extra


def _doc_as_int(stream: rr.RecordingStream) -> None:
    stream.set_time("tick", sequence=3)
    stream.log(STAGES_DOC, components("TextDocument", {"text": [7]}))


COLUMN_CASES: dict[str, dict[str, Any]] = {
    "position-two-floats": {"ee": _ee_with(position=[0.5, 0.1])},
    "position-four-floats": {"ee": _ee_with(position=[0.5, 0.1, 0.2, 0.3])},
    "position-strings": {"ee": _ee_with(position=["a", "b", "c"])},
    "position-float32": {"ee": _ee_with(position=np.array([0.5, 0.0, 0.3], dtype=np.float32))},
    "position-huge": {"ee": _ee_with(position=[1e300, 0.0, 0.3])},
    "position-outside-the-cell": {"ee": _ee_with(position=[50.0, 0.0, 0.3])},
    "position-nan": {"ee": _ee_with(position=[float("nan"), 0.0, 0.3])},
    "quaternion-zero": {"ee": _ee_with(quaternion=[0.0, 0.0, 0.0, 0.0])},
    "quaternion-three": {"ee": _ee_with(quaternion=[0.0, 1.0, 0.0])},
    "stage-huge": {"ee": _ee_with(stage=[2**62])},
    "stage-unsigned": {"ee": _ee_with(stage=np.array([0], dtype=np.uint64))},
    "stage-two": {"ee": _ee_with(stage=[0, 1])},
    "t-infinite": {"ee": _ee_with(t=[float("inf")])},
    "mode-escape": {"ee": _ee_with(mode=["tele\x1b[2Jop"])},
    "mode-integer": {"ee": _ee_with(mode=[5])},
    "deflection-two": {"ee": _ee_with(deflection=[1.0, 0.0])},
    "tick-huge": {"extra": _sample_at(2**62)},
    "tick-negative": {"extra": _sample_at(-5)},
    "tick-a-duration": {"tick_kind": "duration"},
    "mode-integer-list": {"ee": _ee_with(mode=pa.array([5], type=pa.int32()))},
    "log-row-escape": {"extra": _text("stage_done stage=\x1b[2Jpick goal=banana")},
    "log-row-bidi": {"extra": _text("commit goal=ban\u202eana p=0.95")},
    "commit-p-5": {"extra": _text("commit goal=banana p=5.0")},
    "commit-p-negative": {"extra": _text("commit goal=banana p=-0.5")},
    "commit-goal-long": {"extra": _text("commit goal=" + "b" * 500 + " p=0.95")},
    "posterior-2": {"extra": _posterior(2.0)},
    "posterior-infinite": {"extra": _posterior(float("inf"))},
    "stage-doc-an-integer": {"extra": _doc_as_int},
}


def column_cases(box: Box) -> list[Case]:
    text = json.dumps(valid_doc())
    cases = []
    for label, spec in COLUMN_CASES.items():
        path = write_recording(box.path(label), text, ee=spec.get("ee", ee_components),
                               extra=spec.get("extra"),
                               tick_kind=spec.get("tick_kind", "sequence"))  # fmt: skip
        cases.append(box.case(f"columns/{label}", ["replay", "{f}"], path))
    return cases


# --- damaged files ------------------------------------------------------------------------------


def rerun_reads(path: Path) -> bool:
    """Whether rerun's own reader decodes every message of ``path`` (legws not involved)."""
    out = subprocess.run(
        [rerun_cli(), "rrd", "optimize", str(path)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=60, check=False,
        env={**os.environ, "RUST_LOG": "off"},
    )  # fmt: skip
    return out.returncode == 0


def flipped(data: bytes, bits: int, seed: int) -> bytes:
    """``data`` with ``bits`` bits flipped at random places after the stream header."""
    rng = random.Random(seed)
    out = bytearray(data)
    for _ in range(bits):
        i = rng.randrange(12, len(out))
        out[i] ^= 1 << rng.randrange(8)
    return bytes(out)


def damaged_files(box: Box, raw: bytes) -> dict[str, bytes]:
    """Damaged variants of the raw recording ``raw``, by label."""
    files: dict[str, bytes] = {}
    probe = box.root / "probe.rrd"
    ends = set(scan_ends(raw, probe))
    for fraction in (0.08, 0.5, 0.97):
        cut = int(len(raw) * fraction)
        while cut in ends:  # in the middle of a message, as a crash leaves it
            cut += 1
        files[f"truncated-{int(fraction * 100)}pct"] = raw[:cut]
    files["truncated-in-a-header"] = raw[: max(ends - {len(raw)}) + 7]
    for bits, seed in ((1, 1), (20, 2), (200, 3)):
        for attempt in range(50):  # flips rerun itself cannot read (see the module's notes)
            data = flipped(raw, bits, seed * 1000 + attempt)
            probe.write_bytes(data)
            if not rerun_reads(probe):
                files[f"flipped-{bits}-bits"] = data
                break
        else:
            raise AssertionError(f"no seed of {bits} flipped bits damages the recording")
    files["header-overwritten"] = b"\0" * 12 + raw[12:]
    files["header-garbage"] = random.Random(4).randbytes(12) + raw[12:]
    files["header-newer-rerun"] = raw[:4] + bytes([9, 9, 9, 0]) + raw[8:]
    files["header-options"] = raw[:8] + b"\x07\x07\x00\x00" + raw[12:]
    probe.unlink(missing_ok=True)
    return files


def scan_ends(data: bytes, probe: Path) -> list[int]:
    probe.write_bytes(data)
    return list(scan(probe).ends)


def foreign_recording(path: Path) -> Path:
    """A recording someone else's program wrote: points, no legws entities."""
    stream = rr.RecordingStream("someone-else")
    stream.save(path)
    for k in range(20):
        stream.set_time("frame", sequence=k)
        stream.log("points", rr.Points3D(np.random.default_rng(k).random((50, 3))))
    stream.disconnect()
    return path


def finished_recording(path: Path) -> Path:
    """A recording the daemon finished (with rerun's footer)."""
    with RerunLog(f"save:{path}", robot="sawyer-sim") as log:
        log_episode(log, straight_episode("breakfast_easy", "banana", hold=2), stage="easy")
    return path


def damaged_cases(box: Box, raw: bytes) -> list[Case]:
    cases = []
    for label, data in damaged_files(box, raw).items():
        path = box.path(label)
        path.write_bytes(data)
        cases += [box.case(f"damaged/{label}/{t[0]}", t, path) for t in COMMANDS]
    foreign = foreign_recording(box.path("foreign"))
    cases += [box.case(f"damaged/foreign/{t[0]}", t, foreign) for t in COMMANDS]
    raw_foreign = box.path("foreign-raw")
    raw_foreign.write_bytes(_unfinished(foreign.read_bytes()))
    cases += [box.case(f"damaged/foreign-raw/{t[0]}", t, raw_foreign) for t in COMMANDS]
    finished = finished_recording(box.root / "finished.rrd").read_bytes()
    footer = scan_ends(finished, box.root / "probe.rrd")[-1]
    broken = bytearray(finished)
    for i in range(footer - 200, footer - 100, 7):  # inside the footer's manifest
        broken[i] ^= 0x55
    path = box.path("footer-damaged")
    path.write_bytes(bytes(broken))
    cases += [box.case(f"damaged/footer/{COMMANDS[0][0]}", COMMANDS[0], path)]
    (box.root / "finished.rrd").unlink()
    (box.root / "probe.rrd").unlink(missing_ok=True)
    return cases


def _unfinished(data: bytes) -> bytes:
    """A finished stream without its footer (the end-of-stream message and the trailer)."""
    import struct

    off = 12
    while off < len(data):
        kind, length = struct.unpack_from("<QQ", data, off)
        if kind == 0:
            return data[:off]
        off += 16 + length
    return data


# --- links --------------------------------------------------------------------------------------


def link_cases(box: Box, raw: bytes) -> list[Case]:
    cases = []
    dangling = box.path("dangling-link")
    dangling.symlink_to(box.root / "in" / "nothing-here.rrd")
    cases += [box.case(f"links/dangling/{t[0]}", t, dangling) for t in COMMANDS]
    target = box.path("cut-target", "target.rrd")
    target.write_bytes(raw[: len(raw) // 2 + 3])
    link = target.parent / "session.rrd"
    link.symlink_to(target.name)
    cases += [box.case(f"links/to-a-cut-recording/{t[0]}", t, link) for t in COMMANDS]
    return cases


def all_cases(box: Box, group: str, raw: bytes) -> list[Case]:
    if group == "docs":
        return doc_cases(box)
    if group == "columns":
        return column_cases(box)
    if group == "damaged":
        return damaged_cases(box, raw)
    return link_cases(box, raw)
