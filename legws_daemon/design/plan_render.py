"""The picture of one planned decision: the top view of its layout with its targets marked.

:func:`~legws_daemon.robot.render.render_layout` draws a grasp marker on each of the
scene's candidate goals; here they are the decision's candidates that are objects (a
place or dip target sits right above its object's marker). Every target, places such as
the feeding scene's mouth included, then gets a labelled ring drawn over the picture at
its position in the table plane; a target beyond the picture's edge is drawn at the edge.
"""

from __future__ import annotations

import copy
import io
from collections.abc import Mapping, Sequence

import numpy as np
from PIL import Image, ImageDraw

from legws_daemon.robot.render import render_layout, top_pixel
from legws_daemon.scene.scene import ObjectPose, Scene
from legws_daemon.task.targets import Target

WIDTH, HEIGHT = 800, 600
#: Ring colour (RGB), the render's marker magenta.
RING = (255, 26, 217)
RING_RADIUS = 16
#: Distance kept from the picture's edge by rings of targets outside the view, pixels.
EDGE = 24


def decision_picture(
    scene: Scene,
    layout: Mapping[str, ObjectPose],
    targets: Sequence[Target],
    title: str,
    width: int = WIDTH,
    height: int = HEIGHT,
    arm: str = "sawyer",
) -> bytes:
    """PNG bytes of the top view of ``layout`` with ``targets`` marked and a title line.

    Raises:
        RenderUnavailableError: no OpenGL context.
    """
    view = copy.copy(scene)  # a shallow copy whose candidate goals are the decision's
    objects = tuple(t.name for t in targets if t.name in scene.objects)
    view.goal_names = objects or scene.goal_names
    image = Image.fromarray(render_layout(view, dict(layout), width, height, "top", arm))
    draw = ImageDraw.Draw(image)
    for t in targets:
        row, col = top_pixel(scene, width, height, float(t.position[0]), float(t.position[1]))
        inside = 0 <= row <= height and 0 <= col <= width
        r = float(np.clip(row, EDGE, height - EDGE))
        c = float(np.clip(col, EDGE, width - EDGE))
        box = (c - RING_RADIUS, r - RING_RADIUS, c + RING_RADIUS, r + RING_RADIUS)
        draw.ellipse(box, outline=RING, width=3)
        label = f"{t.name} ({t.action})" + ("" if inside else " (beyond the view)")
        tx = c + RING_RADIUS + 4 if c < width * 0.7 else c - RING_RADIUS - 8 * len(label)
        _text(draw, (tx, r - 6), label)
    _text(draw, (8, 8), title)
    buf = io.BytesIO()
    image.save(buf, format="PNG")
    return buf.getvalue()


def _text(draw: ImageDraw.ImageDraw, xy: tuple[float, float], text: str) -> None:
    """White text on a dark box, readable on any background."""
    left, top, right, bottom = draw.textbbox(xy, text)
    draw.rectangle((left - 3, top - 2, right + 3, bottom + 2), fill=(20, 20, 20))
    draw.text(xy, text, fill=(255, 255, 255))
