"""Hostile inputs by class, not by case: generators the corpus (:mod:`.corpus`) runs through
every command of every kind of file.

- **depth**: nesting just below and far above what Python's parsers recurse into (JSON
  arrays and objects of 985 levels, under ``json.loads``' own limit; TOML arrays and
  inline tables of 900 and 5,000 levels);
- **key paths**: TOML dotted keys and table headers of 5,000 parts, and of 100,000 parts
  in 200 KB (under the size limit: the case ``tomllib`` parses in quadratic time);
- **sizes**: a file just under its kind's size limit that is valid up to its last line or
  holds one huge array (what is read must stay within memory and time);
- **paths**: a path component of 300 characters, a path of 5,000 characters, a loop of
  links, a file nobody may read (skipped as root, who may read anything);
- **images** (:func:`image_cases`): picture headers that promise more pixels than memory
  holds (PNG, BMP, TIFF, JPEG), a zero-sized one, one cut off after its header.

The contract is the corpus's: exit 2, one ``legws: error:`` line per error, ≤ 5 s,
≤ 1 GiB, nothing written or damaged.
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from legws_daemon.formats.files import LIMITS

if TYPE_CHECKING:
    from tests.reliability.corpus import Kind

Texts = Iterator[tuple[str, bytes]]


def depth_texts(kind: Kind) -> Texts:
    """Documents nested deeper than any real file, each valid syntax."""
    if kind.fmt in ("json", "json5", "jsonl"):
        yield "json-985-arrays", b"[" * 985 + b"]" * 985
        yield "json-985-objects", b'{"a": ' * 985 + b"1" + b"}" * 985
        yield "json-65-levels", b"[" * 65 + b"]" * 65
    elif kind.fmt == "toml":
        yield "toml-900-arrays", b"a = " + b"[" * 900 + b"]" * 900
        yield "toml-5000-arrays", b"a = " + b"[" * 5000 + b"]" * 5000
        yield "toml-900-inline-tables", b"a = " + b"{b = " * 900 + b"1" + b"}" * 900


def key_path_texts(kind: Kind) -> Texts:
    """TOML keys of many parts (the dotted form nests a table per part)."""
    if kind.fmt != "toml":
        return
    many = ".".join(["a"] * 5000).encode()
    yield "toml-dotted-key-5000", many + b" = 1\n"
    yield "toml-header-5000", b"[" + many + b"]\nx = 1\n"
    yield "toml-array-header-5000", b"[[" + many + b"]]\nx = 1\n"
    yield "toml-quoted-parts-5000", b".".join([b'"a"'] * 5000) + b" = 1\n"
    huge = b".".join([b"a"] * 100_000)  # 200 KB, under every TOML kind's limit
    yield "toml-dotted-key-100000", huge + b" = 1\n"


def size_texts(kind: Kind, valid: bytes) -> Texts:
    """A file just under its size limit: valid lines and a broken last one (line formats),
    or the document with one huge array beside it (an unknown key; cut short at its very
    end where a kind accepts unknown keys)."""
    limit = LIMITS[kind.limit]
    if kind.fmt == "jsonl":
        line = valid.splitlines()[0] + b"\n"
        body = line * ((limit - 100) // len(line))
        yield "just-under-the-limit-broken-at-the-end", body + b'{"seq": "last"}\n'
    elif kind.fmt in ("json", "json5"):
        doc = json.loads(valid)
        marker = "@BULK@"
        if isinstance(doc, dict):
            head = json.dumps({**doc, "zz_bulk": marker})
        elif isinstance(doc, list) and doc and isinstance(doc[0], dict):
            head = json.dumps([{**doc[0], "zz_bulk": marker}])
        else:
            return
        before, after = (s.encode() for s in head.split(f'"{marker}"'))
        n = (limit - len(head) - 100) // 6
        text = before + b"[" + b"0.25, " * n + b"0.25]" + after
        yield (
            "just-under-the-limit-huge-array",
            text[:-1] if "unknown-key" in kind.valid_changes else text,
        )
    elif kind.fmt == "toml":
        n = (limit - len(valid) - 100) // 6
        yield "just-under-the-limit-huge-array", b"zz_bulk = [" + b"0.25, " * n + b"0.25]\n" + valid


#: The path cases (:func:`place_path`): name -> what is put there.
PATH_CASES = ["name-too-long", "path-too-long", "link-loop", "unreadable"]


def place_path(root: Path, folder: Path, filename: str, what: str, data: bytes) -> Path | None:
    """A path under ``folder`` (which exists) that the system refuses in the way ``what``
    says; ``None`` when the case does not apply (``unreadable`` as root)."""
    if what == "name-too-long":
        return folder / ("n" * 300) / filename  # no such component can exist
    if what == "path-too-long":
        return folder.joinpath(*["d" * 250] * 20, filename)  # 5,000 characters
    if what == "link-loop":
        loop = folder / filename
        loop.symlink_to(filename)
        return loop
    if what == "unreadable":
        if os.geteuid() == 0:
            return None
        path = folder / filename
        path.write_bytes(data)
        path.chmod(0)
        return path
    raise ValueError(what)


# --- pictures ---------------------------------------------------------------------------------


def png_header_only(width: int, height: int, rows: int = 16, cut: bool = False) -> bytes:
    """A grey PNG whose header says ``width`` x ``height`` pixels and which holds ``rows`` of
    them (``cut``: nothing after the header): a small file that would decode to any size."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = zlib.crc32(kind + data) & 0xFFFFFFFF
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)

    header = b"\x89PNG\r\n\x1a\n" + chunk(
        b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    )
    if cut:
        return header
    data = zlib.compress(b"\x00" * (min(width, 100_000) + 1) * rows)
    return header + chunk(b"IDAT", data) + chunk(b"IEND", b"")


def _bmp(width: int, height: int) -> bytes:
    info = struct.pack("<IiiHHIIiiII", 40, width, height, 1, 24, 0, 0, 2835, 2835, 0, 0)
    return b"BM" + struct.pack("<IHHI", 14 + 40 + 16, 0, 0, 54) + info + b"\0" * 16


def _tiff(width: int, height: int) -> bytes:
    entries = [(256, 4, 1, width), (257, 4, 1, height), (258, 3, 1, 8), (259, 3, 1, 1),
               (262, 3, 1, 1), (273, 4, 1, 8), (277, 3, 1, 1), (278, 4, 1, height),
               (279, 4, 1, width * height)]  # fmt: skip
    ifd = struct.pack("<H", len(entries))
    for tag, typ, count, value in entries:
        ifd += struct.pack("<HHII", tag, typ, count, value)
    body = b"II*\0" + struct.pack("<I", 16) + b"\0" * 8
    return body + ifd + b"\0\0\0\0"


def _jpeg(width: int, height: int) -> bytes:
    sof = b"\xff\xc0" + struct.pack(">HBHHB", 11, 8, height, width, 1) + b"\x01\x11\x00"
    return b"\xff\xd8" + sof + b"\xff\xd9"


#: Picture files by class: label -> bytes.
PICTURES: dict[str, Callable[[], bytes]] = {
    "png-32000x32000": lambda: png_header_only(32000, 32000),
    "png-65535x65535": lambda: png_header_only(65535, 65535),
    "png-60000x1000": lambda: png_header_only(60_000, 1000, rows=1),
    "png-0x0": lambda: png_header_only(0, 0),
    "png-cut-after-header": lambda: png_header_only(640, 480, cut=True),
    "bmp-30000x30000": lambda: _bmp(30000, 30000),
    "tiff-40000x40000": lambda: _tiff(40000, 40000),
    "jpeg-65500x65500": lambda: _jpeg(65500, 65500),
}


def image_cases(root: Path) -> Iterator[tuple[str, list[str]]]:
    """``(label, argv)`` of ``legws track calibrate`` over each hostile picture."""
    folder = root / "in" / "pictures"
    folder.mkdir(parents=True, exist_ok=True)
    for label, make in PICTURES.items():
        path = folder / f"{label}.png"
        path.write_bytes(make())
        rel = str(path.relative_to(root))
        yield label, ["track", "calibrate", "--images", rel, "--out", "out/calibration.json"]
