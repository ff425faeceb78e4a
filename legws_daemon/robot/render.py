"""Offscreen pictures of a scene layout: a top-down and a perspective view.

The world is composed with the robot's meshes (:class:`~legws_daemon.robot.world.World`),
the arm is put at the EE home pose, and the grasp pose of every candidate goal is drawn
as a small marker: a dot at the grasp point, a stem back along the approach axis and a
bar across the closing direction at the stem's end (a stylised open gripper). Collision
primitives (geom group 3) are hidden; shadows and reflections are off for speed.

MuJoCo picks its OpenGL backend from ``MUJOCO_GL`` when it is first imported; headless
machines need ``egl`` (or ``osmesa``). ``mujoco`` is imported here only when a picture is
rendered, so a missing or broken GL stack becomes one :class:`RenderUnavailableError`
line instead of an import-time traceback.
"""

from __future__ import annotations

import io
import os
import warnings
from collections.abc import Mapping
from pathlib import Path
from types import ModuleType
from typing import Any, Literal

import numpy as np

from legws_daemon.errors import LegwsError
from legws_daemon.formats.files import output_folder, write_atomic
from legws_daemon.scene.scene import ObjectPose, Scene

View = Literal["top", "perspective"]
VIEWS: tuple[View, ...] = ("top", "perspective")
#: Largest picture side, pixels (the offscreen framebuffer is sized to the request).
MAX_SIZE = 4096
#: Debian packages of headless OpenGL (EGL with Mesa, or OSMesa).
GL_PACKAGES = "libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1 libosmesa6"

#: Colour of the grasp markers (RGBA): magenta, unlike every scene object.
MARKER_RGBA = np.array([1.0, 0.1, 0.85, 1.0], dtype=np.float32)
#: Floor under the table (RGBA), so the background is not black.
FLOOR_RGBA = np.array([0.55, 0.57, 0.6, 1.0], dtype=np.float32)
#: Length of a marker's stem along the approach axis and half-width of its bar, metres.
MARKER_STEM = 0.07
MARKER_BAR = 0.035
#: Margin around the table and the robot's base in the top view, metres.
TOP_MARGIN = 0.06
#: Extent of the robot's base around the origin included in the top view, metres.
BASE_EXTENT = 0.16


class RenderUnavailableError(LegwsError):
    """No OpenGL context could be created for offscreen rendering."""


def gl_unavailable(err: BaseException) -> RenderUnavailableError:
    """The one-line error for a failed GL set-up, naming the packages that fix it."""
    backend = os.environ.get("MUJOCO_GL") or "unset"
    detail = (str(err).strip().splitlines() or [type(err).__name__])[0]
    if len(detail) > 160:
        detail = detail[:157] + "..."
    return RenderUnavailableError(
        f"cannot create an OpenGL context for rendering (MUJOCO_GL={backend}: {detail}); "
        f"install the Debian packages {GL_PACKAGES} (apt-get install), then use "
        "MUJOCO_GL=egl, or MUJOCO_GL=osmesa where EGL does not work"
    )


def _import_mujoco() -> ModuleType:
    try:
        with warnings.catch_warnings():  # GLFW warns before it fails: the error says it all
            warnings.simplefilter("ignore")
            import mujoco
    except Exception as err:  # the GL backend is set up at import: any failure is GL's
        raise gl_unavailable(err) from None
    module: ModuleType = mujoco
    return module


def _top_frame(scene: Scene, aspect: float) -> tuple[float, float, float]:
    """Centre ``(x, y)`` and vertical extent (metres) of the top view.

    The view holds the table and the robot's base; image up is +x (away from the robot),
    image left is +y.
    """
    ws = scene.workspace
    cx, cy = ws.table_center
    sx, sy = ws.table_size
    x_lo = min(cx - sx / 2, -BASE_EXTENT) - TOP_MARGIN
    x_hi = cx + sx / 2 + TOP_MARGIN
    y_half = max(abs(cy - sy / 2), abs(cy + sy / 2), BASE_EXTENT) + TOP_MARGIN
    return (x_lo + x_hi) / 2, 0.0, max(x_hi - x_lo, 2 * y_half / aspect)


def top_pixel(scene: Scene, width: int, height: int, x: float, y: float) -> tuple[float, float]:
    """Pixel ``(row, column)`` of the table point ``(x, y)`` in the top view."""
    x0, y0, extent = _top_frame(scene, width / height)
    scale = height / extent  # pixels per metre
    return height / 2 - (x - x0) * scale, width / 2 - (y - y0) * scale


def _top_camera(mujoco: ModuleType, scene: Scene, aspect: float) -> tuple[Any, float]:
    """An orthographic camera straight above the table; the robot's base at the bottom.

    Returns the camera and the vertical extent of the view in metres (the ``fovy`` of an
    orthographic camera).
    """
    x0, y0, extent = _top_frame(scene, aspect)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.orthographic = 1
    cam.lookat[:] = [x0, y0, scene.workspace.table_height]
    cam.azimuth = 0.0  # image up = +x
    cam.elevation = -90.0
    cam.distance = 3.0
    return cam, extent


def _perspective_camera(mujoco: ModuleType, scene: Scene) -> Any:
    """A camera at the robot's front-left (beyond the table, +y side), elevated."""
    ws = scene.workspace
    cx, cy = ws.table_center
    sx, sy = ws.table_size
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = [cx * 0.8, cy, ws.table_height + 0.15]
    cam.azimuth = 215.0  # from +x +y (the robot's front-left), looking back at it
    cam.elevation = -35.0
    cam.distance = float(np.hypot(sx, sy)) + 0.7
    return cam


def _add_geom(
    mujoco: ModuleType,
    scn: Any,
    kind: Any,
    size: list[float],
    pos: np.ndarray,
    rgba: np.ndarray,
    mat: np.ndarray | None = None,
) -> Any:
    if scn.ngeom >= scn.maxgeom:
        return None
    geom = scn.geoms[scn.ngeom]
    rot = np.eye(3) if mat is None else mat
    mujoco.mjv_initGeom(
        geom,
        kind,
        np.asarray(size, dtype=np.float64),
        np.asarray(pos, dtype=np.float64),
        np.asarray(rot, dtype=np.float64).reshape(9),
        rgba,
    )
    geom.category = mujoco.mjtCatBit.mjCAT_DECOR
    scn.ngeom += 1
    return geom


def _add_connector(
    mujoco: ModuleType, scn: Any, a: np.ndarray, b: np.ndarray, width: float, rgba: np.ndarray
) -> None:
    geom = _add_geom(mujoco, scn, mujoco.mjtGeom.mjGEOM_CAPSULE, [0.0, 0.0, 0.0], a, rgba)
    if geom is not None:
        mujoco.mjv_connector(
            geom,
            mujoco.mjtGeom.mjGEOM_CAPSULE,
            width,
            np.asarray(a, dtype=np.float64),
            np.asarray(b, dtype=np.float64),
        )


def _add_markers(mujoco: ModuleType, scn: Any, scene: Scene, poses: dict[str, ObjectPose]) -> None:
    names = scene.goal_names
    arr = np.array([[[poses[n].x, poses[n].y, poses[n].yaw] for n in names]])
    positions, rotations, _ = scene.grasp_batch(names, arr)
    for p, R in zip(positions[0], rotations[0], strict=True):
        z, x = R[:, 2], R[:, 0]
        back = p - MARKER_STEM * z
        _add_geom(mujoco, scn, mujoco.mjtGeom.mjGEOM_SPHERE, [0.011, 0, 0], p, MARKER_RGBA)
        _add_connector(mujoco, scn, p, back, 0.004, MARKER_RGBA)
        _add_connector(
            mujoco, scn, back - MARKER_BAR * x, back + MARKER_BAR * x, 0.006, MARKER_RGBA
        )


def _add_floor(mujoco: ModuleType, scn: Any, scene: Scene) -> None:
    ws = scene.workspace
    floor_z = ws.table_height - 0.75
    pos = np.array([ws.table_center[0], ws.table_center[1], floor_z])
    _add_geom(mujoco, scn, mujoco.mjtGeom.mjGEOM_PLANE, [40.0, 40.0, 0.1], pos, FLOOR_RGBA)


def _soften_lights(model: Any, view: View) -> None:
    """Light the scene so colours stay true: no surface lit past white, few highlights.

    The model's defaults (a headlight plus a spotlight above the table) saturate the top
    faces in a top view, where both lights shine along the view axis.
    """
    head = model.vis.headlight
    if view == "top":
        head.ambient[:], head.diffuse[:], head.specular[:] = 0.35, 0.2, 0.0
        model.light_diffuse[:] = 0.45
    else:
        head.ambient[:], head.diffuse[:], head.specular[:] = 0.3, 0.35, 0.1
        model.light_diffuse[:] = 0.45
    model.light_specular[:] = 0.1


def render_layout(
    scene: Scene,
    layout: Mapping[str, ObjectPose] | None,
    width: int = 800,
    height: int = 600,
    view: View = "top",
    arm: str = "sawyer",
) -> np.ndarray:
    """Render ``scene`` with ``layout`` (``None``: the scene file's poses), the arm
    ``arm`` at its home pose.

    Returns:
        ``(height, width, 3)`` uint8 RGB image.

    Raises:
        RenderUnavailableError: no OpenGL context (one line naming the packages to install).
    """
    if view not in VIEWS:
        raise ValueError(f"unknown view {view!r}; expected one of {VIEWS}")
    if not (1 <= width <= MAX_SIZE and 1 <= height <= MAX_SIZE):
        raise ValueError(f"image size must be within 1..{MAX_SIZE} pixels")
    mujoco = _import_mujoco()
    from legws_daemon.robot.kinematics import home_configuration
    from legws_daemon.robot.world import World

    poses = scene.poses(layout)
    world = World(scene, arm=arm, visual=True)
    world.set_layout(poses)
    home_configuration(world, scene.home.position, scene.home.rotation)
    model, data = world.model, world.data
    mujoco.mj_forward(model, data)
    model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), width)
    model.vis.global_.offheight = max(int(model.vis.global_.offheight), height)

    _soften_lights(model, view)
    option = mujoco.MjvOption()
    option.geomgroup[:] = 0
    option.geomgroup[0] = 1  # table and objects
    option.geomgroup[1] = 1  # robot meshes and gripper
    option.sitegroup[:] = 0
    if view == "top":
        camera, extent = _top_camera(mujoco, scene, width / height)
        model.vis.global_.fovy = extent  # an orthographic camera's fovy is a length
    else:
        camera = _perspective_camera(mujoco, scene)
        model.vis.global_.fovy = 45.0

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            renderer = mujoco.Renderer(model, height=height, width=width)
    except Exception as err:  # EGL/OSMesa/GLFW each fail their own way: all mean "no GL"
        raise gl_unavailable(err) from None
    try:
        scn = renderer.scene
        scn.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
        scn.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
        renderer.update_scene(data, camera=camera, scene_option=option)
        _add_floor(mujoco, scn, scene)
        _add_markers(mujoco, scn, scene, poses)
        image = renderer.render()
    finally:
        renderer.close()
    return np.ascontiguousarray(image, dtype=np.uint8)


def save_png(image: np.ndarray, path: str | Path) -> Path:
    """Write ``image`` (``(H, W, 3)`` uint8) as a PNG, atomically; creates the folder.

    The picture is written to a temporary file in the same folder, then renamed over
    ``path``: a reader never sees half a file.
    """
    from PIL import Image

    path = Path(path)
    output_folder(path.parent)
    buf = io.BytesIO()
    Image.fromarray(np.asarray(image, dtype=np.uint8)).save(buf, format="PNG")
    return write_atomic(path, buf.getvalue())
