"""A camera in the MuJoCo stand-in: the scene rendered with its fiducial markers.

The world is the scene's (:class:`~legws_daemon.robot.world.World`: table, objects, the
Sawyer with its meshes, the arm at the EE home pose) with every marker added as a thin
textured decal (0.2 mm thick, no collisions, geom group 0): each table marker lying on the
table at its pose, each object's marker centred on its top face and moving with it. A
decal carries the marker's picture with its white margin (:data:`.markers.QUIET_CELLS`).

The default camera stands beyond the table's far edge (away from the robot), high above
it, and looks down at the table's centre, image up towards the robot. From there the arm
at home hides about 1 % of the area objects may occupy (the gripper's fingertips cover a
spot around ``x = 0.3, y = 0`` on the tea table); a camera straight above the table loses
7 to 10 % behind the elbow and wrist, a higher one more. At 640 × 480 it resolves 0.42 to
0.5 pixel per millimetre. Its field of view is the narrowest that shows the whole table.
The camera is an ideal pinhole: :attr:`SimCamera.intrinsics` is exact, with OpenCV's pixel
centre convention (``cx = (w - 1) / 2``).

MuJoCo is imported when a camera is made, so a missing GL stack is one
:class:`~legws_daemon.robot.render.RenderUnavailableError` line.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from types import ModuleType, TracebackType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray, matrix_to_quat, yaw_quat
from legws_daemon.errors import InputError
from legws_daemon.robot.render import MAX_SIZE, _import_mujoco, gl_unavailable
from legws_daemon.scene.scene import ObjectPose, Scene
from legws_daemon.tracking.camera import CameraPose, Intrinsics
from legws_daemon.tracking.markers import (
    QUIET_CELLS,
    SceneMarkers,
    cells,
    marker_image,
    scene_markers,
)

#: Half the thickness of a marker decal, m.
DECAL_HALF_THICKNESS = 0.0001
#: Texture pixels per marker cell.
TEXTURE_CELL_PIXELS = 16
#: Default camera: this far beyond the table's far edge and this high above the table, m.
CAMERA_BEYOND = 0.35
CAMERA_HEIGHT = 1.4
#: Margin between the table's corners and the image border, pixels.
VIEW_MARGIN = 8.0
#: Name of the camera in the compiled model.
CAMERA_NAME = "tracker"


def default_camera_pose(scene: Scene) -> CameraPose:
    """Beyond the table's far edge, :data:`CAMERA_HEIGHT` above it, looking at its centre,
    image up towards the robot (the base frame's −x)."""
    ws = scene.workspace
    cx, cy = ws.table_center
    eye = (cx + ws.table_size[0] / 2 + CAMERA_BEYOND, cy, ws.table_height + CAMERA_HEIGHT)
    return CameraPose.look_at(eye, (cx, cy, ws.table_height), up=(-1.0, 0.0, 0.0))


def table_corners(scene: Scene) -> FloatArray:
    """The table top's four corners ``(4, 3)`` in the base frame."""
    ws = scene.workspace
    (cx, cy), (sx, sy) = ws.table_center, ws.table_size
    xy = np.array([[cx + a * sx / 2, cy + b * sy / 2] for a in (-1, 1) for b in (-1, 1)])
    return np.column_stack([xy, np.full(4, ws.table_height)])


def fitting_fovy(pose: CameraPose, points: ArrayLike, width: int, height: int) -> float:
    """The narrowest vertical field of view, degrees, of a centred pinhole camera at
    ``pose`` whose ``width × height`` image holds ``points`` ``(N, 3)`` (in front of it)
    :data:`VIEW_MARGIN` pixels inside its border."""
    local = (np.asarray(points, dtype=np.float64) - pose.position) @ np.asarray(pose.rotation)
    if np.any(local[:, 2] <= 0.0):
        raise InputError("the camera must see the whole table in front of it")
    tx = np.max(np.abs(local[:, 0] / local[:, 2]))
    ty = np.max(np.abs(local[:, 1] / local[:, 2]))
    focal = min((width / 2 - VIEW_MARGIN) / tx, (height / 2 - VIEW_MARGIN) / ty)
    return math.degrees(2 * math.atan(height / 2 / focal))


def decal_half_side(markers: SceneMarkers, size: float) -> float:
    """Half the side of the decal of a marker of side ``size``, its white margin included."""
    n = cells(markers.dictionary)
    return size * (n + 2 * QUIET_CELLS) / n / 2


def add_marker_decals(mujoco: ModuleType, spec: Any, markers: SceneMarkers) -> None:
    """Add every marker of the scene to ``spec`` as a textured decal (see the module)."""
    table_z = markers.table_height + DECAL_HALF_THICKNESS
    for m in markers.table.values():
        quat = yaw_quat(m.yaw)
        _add_decal(mujoco, spec, markers, spec.worldbody, m.id, m.size, [m.x, m.y, table_z], quat)
    for o in markers.objects.values():
        body = spec.body(f"obj/{o.object}")
        pos = [0.0, 0.0, o.height / 2 + DECAL_HALF_THICKNESS]  # the body is at mid-height
        _add_decal(mujoco, spec, markers, body, o.id, o.size, pos, [1.0, 0.0, 0.0, 0.0])


def _add_decal(
    mujoco: ModuleType,
    spec: Any,
    markers: SceneMarkers,
    parent: Any,
    marker_id: int,
    size: float,
    pos: list[float],
    quat: ArrayLike,
) -> None:
    picture = marker_image(markers.dictionary, marker_id, TEXTURE_CELL_PIXELS)
    name = f"marker/{marker_id}"
    texture = spec.add_texture(
        name=name,
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        width=picture.shape[1],
        height=picture.shape[0],
        nchannel=3,
    )
    texture.data = np.repeat(picture[:, :, None], 3, axis=2).tobytes()
    material = spec.add_material(name=name, specular=0.0, shininess=0.0, reflectance=0.0)
    material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = name
    half = decal_half_side(markers, size)
    parent.add_geom(
        name=name,
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[half, half, DECAL_HALF_THICKNESS],
        pos=pos,
        quat=quat,
        material=name,
        contype=0,
        conaffinity=0,
        group=0,
    )


def _mujoco_camera_quat(pose: CameraPose) -> FloatArray:
    """MuJoCo's camera looks along its −z with y up: OpenCV's axes with y and z negated."""
    r = np.asarray(pose.rotation, dtype=np.float64)
    return matrix_to_quat(np.column_stack([r[:, 0], -r[:, 1], -r[:, 2]]))


class SimCamera:
    """A fixed camera rendering the scene with its markers, as a UVC camera would give it.

    Args:
        scene: the scene; it must have a ``[markers]`` table.
        layout: the objects' poses (``None``: the scene file's).
        width, height: image size, pixels.
        pose: where the camera is (default :func:`default_camera_pose`).
        fovy: vertical field of view, degrees (default: the narrowest holding the table).

    Raises:
        InputError: the scene has no markers, or a bad size or layout.
        RenderUnavailableError: no OpenGL context.
    """

    def __init__(
        self,
        scene: Scene,
        layout: Mapping[str, ObjectPose] | None = None,
        width: int = 640,
        height: int = 480,
        *,
        pose: CameraPose | None = None,
        fovy: float | None = None,
    ) -> None:
        if not (1 <= width <= MAX_SIZE and 1 <= height <= MAX_SIZE):
            raise InputError(f"image size must be within 1..{MAX_SIZE} pixels")
        mujoco = _import_mujoco()
        from legws_daemon.robot.kinematics import home_configuration
        from legws_daemon.robot.world import World

        self.scene = scene
        self.markers = scene_markers(scene)
        self.pose = pose if pose is not None else default_camera_pose(scene)
        fovy = (
            fovy
            if fovy is not None
            else fitting_fovy(self.pose, table_corners(scene), width, height)
        )
        self.intrinsics = Intrinsics.pinhole(fovy, width, height)

        def decorate(spec: Any) -> None:
            add_marker_decals(mujoco, spec, self.markers)
            spec.worldbody.add_camera(
                name=CAMERA_NAME,
                pos=list(self.pose.position),
                quat=list(_mujoco_camera_quat(self.pose)),
                fovy=fovy,
            )

        self.world = World(scene, visual=True, decorate=decorate)
        home_configuration(self.world, scene.home.position, scene.home.rotation)
        self._mujoco = mujoco
        self._setup_model(width, height)
        self._option = mujoco.MjvOption()
        self._option.geomgroup[:] = 0
        self._option.geomgroup[0] = 1  # table, objects, marker decals
        self._option.geomgroup[1] = 1  # robot meshes and gripper
        self._option.sitegroup[:] = 0
        self._renderer = self._make_renderer(width, height)
        self.set_layout(scene.poses(layout))  # the scene file's poses for the others

    def _setup_model(self, width: int, height: int) -> None:
        """Even light without highlights (a printed marker is matte), framebuffer size."""
        model = self.world.model
        global_ = model.vis.global_
        global_.offwidth = max(int(global_.offwidth), width)
        global_.offheight = max(int(global_.offheight), height)
        head = model.vis.headlight
        head.ambient[:], head.diffuse[:], head.specular[:] = 0.35, 0.3, 0.0
        model.light_diffuse[:] = 0.4
        model.light_specular[:] = 0.0

    def _make_renderer(self, width: int, height: int) -> Any:
        mujoco = self._mujoco
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                renderer = mujoco.Renderer(self.world.model, height=height, width=width)
        except Exception as err:  # EGL/OSMesa/GLFW each fail their own way: all mean "no GL"
            raise gl_unavailable(err) from None
        renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
        renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
        return renderer

    def set_layout(self, layout: Mapping[str, ObjectPose]) -> None:
        """Move the named objects, fixed ones too (others keep their pose). An object may
        be put anywhere, e.g. off the table and out of view: only the names are checked."""
        unknown = [n for n in layout if n not in self.scene.objects]
        if unknown:
            raise InputError(f"unknown object '{unknown[0]}' in scene '{self.scene.name}'")
        self.world.set_layout(layout)

    def render(self, layout: Mapping[str, ObjectPose] | None = None) -> np.ndarray:
        """The picture ``(height, width, 3)`` ``uint8`` in BGR order (OpenCV's), after
        moving the objects of ``layout`` if given."""
        if layout is not None:
            self.set_layout(layout)
        self._renderer.update_scene(self.world.data, camera=CAMERA_NAME, scene_option=self._option)
        rgb = self._renderer.render()
        return np.ascontiguousarray(rgb[:, :, ::-1], dtype=np.uint8)

    def close(self) -> None:
        """Free the renderer's GL context."""
        self._renderer.close()

    def __enter__(self) -> SimCamera:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
