"""A picture of a task graph: a box per stage, an arrow per transition, choices in colour.

Stages stand in columns by their longest distance from the start (left to right), in file
order within a column. A box shows the stage's name, action, prompt and candidates, and
says "no inference" when the stage has a single candidate. Arrows into the next column
are straight; arrows that skip columns (an optional step) run along lanes below the
boxes, sharing a lane where they do not overlap. The arrows of a choice (a stage with
several successors: the daemon infers over the union of their candidates) are orange; a
graph that repeats has a dashed arrow from each end stage back to the start along a lane
above the boxes. Layout and drawing grow with stages and transitions, never with paths; a
diagram over :data:`MAX_PIXELS` is refused (one error line).
"""

from __future__ import annotations

import io
import itertools
import textwrap

from PIL import Image, ImageDraw, ImageFont

from legws_daemon.errors import InputError
from legws_daemon.task.graph import Stage, TaskGraph

BOX_WIDTH = 250
GAP_X = 80
GAP_Y = 30
MARGIN = 24
PAD = 8
LINE = 18
LANE = 16
WRAP = 30  # characters per line inside a box
#: The largest diagram drawn, pixels (below Pillow's decompression-bomb warning at about
#: 89 million): a chain of 64 stages takes about 5 million, 64 stages of 10 successors each
#: about 26 million (their arrows that skip columns sharing about 60 lanes).
MAX_PIXELS = 50_000_000

BACKGROUND = (255, 255, 255)
INK = (40, 40, 40)
BOX_FILL = (236, 242, 250)
SINGLE_FILL = (242, 242, 242)
PLAIN = (90, 90, 90)
CHOICE = (230, 120, 0)
REPEAT = (40, 90, 200)

Font = ImageFont.FreeTypeFont | ImageFont.ImageFont
Point = tuple[float, float]
Box = tuple[float, float, float, float]


def _font(size: int) -> Font:
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: one bitmap size
        return ImageFont.load_default()


def levels(graph: TaskGraph) -> dict[str, int]:
    """Longest distance of each stage from the start (the graph is a DAG): one pass in
    topological order."""
    level = dict.fromkeys(graph.stages, 0)
    for name in graph.order():
        for n in graph.stages[name].next:
            level[n] = max(level[n], level[name] + 1)
    return level


def lanes(spans: list[tuple[float, float]], gap: float = 0.0) -> list[int]:
    """A lane for each horizontal span ``(left, right)``: spans closer than ``gap`` get
    different lanes, and no more lanes are used than the most spans over one point need
    (the spans by their left end, each into the first lane free by then)."""
    out = [0] * len(spans)
    ends: list[float] = []  # the right end of each lane's last span
    for i in sorted(range(len(spans)), key=lambda i: spans[i]):
        left, right = spans[i]
        lane = next((k for k, end in enumerate(ends) if end + gap < left), len(ends))
        if lane == len(ends):
            ends.append(right)
        else:
            ends[lane] = right
        out[i] = lane
    return out


def _centre(box: Box) -> float:
    return (box[0] + box[2]) / 2


def box_lines(stage: Stage, fixed: tuple[str, ...] = ()) -> list[str]:
    """The text of a stage's box, title first."""
    names = [f"{c} (fixed)" if c in fixed else c for c in stage.candidates]
    lines = [stage.name, f"action: {stage.action}"]
    if stage.prompt:
        lines += textwrap.wrap(f'"{stage.prompt}"', WRAP)
    lines += textwrap.wrap("candidates: " + ", ".join(names), WRAP)
    if len(stage.candidates) == 1:
        lines.append("no inference (one candidate)")
    return lines


def _arrow(
    draw: ImageDraw.ImageDraw,
    points: list[Point],
    colour: tuple[int, int, int],
    dashed: bool = False,
) -> None:
    for a, b in itertools.pairwise(points):
        if dashed:
            _dashes(draw, a, b, colour)
        else:
            draw.line([a, b], fill=colour, width=2)
    (x0, y0), (x1, y1) = points[-2], points[-1]
    length = max(((x1 - x0) ** 2 + (y1 - y0) ** 2) ** 0.5, 1e-9)
    ux, uy = (x1 - x0) / length, (y1 - y0) / length
    head = [
        (x1, y1),
        (x1 - 10 * ux - 5 * uy, y1 - 10 * uy + 5 * ux),
        (x1 - 10 * ux + 5 * uy, y1 - 10 * uy - 5 * ux),
    ]
    draw.polygon(head, fill=colour)


def _dashes(draw: ImageDraw.ImageDraw, a: Point, b: Point, colour: tuple[int, int, int]) -> None:
    length = max(((b[0] - a[0]) ** 2 + (b[1] - a[1]) ** 2) ** 0.5, 1e-9)
    n = max(int(length // 8), 1)
    for i in range(0, n, 2):
        t0, t1 = i / n, min((i + 1) / n, 1.0)
        p0 = (a[0] + (b[0] - a[0]) * t0, a[1] + (b[1] - a[1]) * t0)
        p1 = (a[0] + (b[0] - a[0]) * t1, a[1] + (b[1] - a[1]) * t1)
        draw.line([p0, p1], fill=colour, width=2)


def _placement(graph: TaskGraph, top: float) -> dict[str, Box]:
    level = levels(graph)
    columns: dict[int, list[str]] = {}
    for name in graph.stages:
        columns.setdefault(level[name], []).append(name)
    height = {n: 2 * PAD + LINE * len(box_lines(s, graph.fixed)) for n, s in graph.stages.items()}
    rows = max(len(c) for c in columns.values())
    row_h = [
        max((height[c[r]] for c in columns.values() if r < len(c)), default=0) for r in range(rows)
    ]
    boxes: dict[str, Box] = {}
    for col, names in columns.items():
        x = MARGIN + col * (BOX_WIDTH + GAP_X)
        for r, name in enumerate(names):
            y = top + sum(row_h[:r]) + r * GAP_Y
            boxes[name] = (x, y, x + BOX_WIDTH, y + height[name])
    return boxes


def diagram_png(graph: TaskGraph) -> bytes:
    """The graph as a PNG diagram."""
    font, bold = _font(13), _font(15)
    ends = [s.name for s in graph.stages.values() if not s.next]
    repeats = graph.repeat == "until_consumed"
    header = MARGIN + 2 * LINE + 8
    top = header + (len(ends) * LANE + LINE + 12 if repeats else 12)
    boxes = _placement(graph, top)
    level = levels(graph)
    skips = [
        (s.name, n) for s in graph.stages.values() for n in s.next if level[n] != level[s.name] + 1
    ]
    spans = [(_centre(boxes[a]), _centre(boxes[b]) - 12) for a, b in skips]
    lane_of = dict(zip(skips, lanes(spans, gap=2 * LANE), strict=True))
    bottom = max(b[3] for b in boxes.values())
    width = max(int(max(b[2] for b in boxes.values()) + MARGIN), 520)
    height = int(bottom + 12 + (max(lane_of.values(), default=-1) + 1) * LANE + MARGIN)
    if width * height > MAX_PIXELS:
        raise InputError(
            f"the diagram would be {width}x{height} pixels, more than "
            f"{MAX_PIXELS // 10**6} million: too large to draw; without --png the graph is "
            "printed as text", source=graph.source or None
        )  # fmt: skip
    image = Image.new("RGB", (width, height), BACKGROUND)
    draw = ImageDraw.Draw(image)
    title = f"task graph '{graph.name}' (scene {graph.scene}), repeat: {graph.repeat}"
    draw.text((MARGIN, MARGIN), title, fill=INK, font=bold)
    legend = "orange: a choice, inferred over the alternatives' candidates"
    if repeats:
        legend += "; blue dashed: repeat"
    draw.text((MARGIN, MARGIN + LINE + 2), legend, fill=PLAIN, font=font)
    for name, s in graph.stages.items():
        x0, y0, x1, y1 = boxes[name]
        fill = SINGLE_FILL if len(s.candidates) == 1 else BOX_FILL
        outline = CHOICE if len(s.next) > 1 else INK
        draw.rounded_rectangle((x0, y0, x1, y1), radius=6, fill=fill, outline=outline, width=2)
        for i, text in enumerate(box_lines(s, graph.fixed)):
            draw.text(
                (x0 + PAD, y0 + PAD + i * LINE), text, fill=INK, font=bold if i == 0 else font
            )
    for s in graph.stages.values():
        colour = CHOICE if len(s.next) > 1 else PLAIN
        a = boxes[s.name]
        for n in s.next:
            b = boxes[n]
            if (s.name, n) in lane_of:
                y = bottom + 12 + lane_of[s.name, n] * LANE
                ax, bx = _centre(a), _centre(b) - 12
                _arrow(draw, [(ax, a[3]), (ax, y), (bx, y), (bx, b[3])], colour)
            else:
                _arrow(draw, [(a[2], (a[1] + a[3]) / 2), (b[0], (b[1] + b[3]) / 2)], colour)
    if repeats:
        start = boxes[graph.start]
        sx = (start[0] + start[2]) / 2 + 12
        for k, name in enumerate(ends):
            e = boxes[name]
            y = top - 12 - k * LANE
            ex = (e[0] + e[2]) / 2
            _arrow(draw, [(ex, e[1]), (ex, y), (sx, y), (sx, start[1])], REPEAT, dashed=True)
        y = top - 12 - (len(ends) - 1) * LANE - LINE
        draw.text((sx + 16, y), "repeat until consumed", fill=REPEAT, font=font)
    buf = io.BytesIO()
    image.save(buf, format="PNG")
    return buf.getvalue()
