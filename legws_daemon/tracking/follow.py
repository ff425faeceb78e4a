"""The layout the daemon runs, for the stand-in's camera (``legws track --source sim:``).

The daemon's status carries ``layout`` (docs/messages.md): its scene's name and where
every object should stand in the current decision — the plan's layout of it
(``--plan``), else the daemon's ``--layout`` or the scene file's poses. The tracker hears
the status on its own session (:class:`DaemonLayout`, fed by a zenoh subscriber) and
renders that layout, again whenever it changes (a new decision of a plan, a load), so the
camera and the daemon cannot disagree about where the objects were put.

What is rendered only while the daemon's layout is known and fits the camera's scene: no
status yet, or one of another scene, is "nothing to show" (the loop publishes nothing and
says why), never a guess from the scene file. A status that does not validate is ignored
(the last good layout stays, as it would on a real table).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence

from legws_daemon.errors import InputError
from legws_daemon.formats.messages import StatusMessage
from legws_daemon.joystick.daemon_status import STATUS_NOTE, StatusWatch
from legws_daemon.scene.scene import Layout, ObjectPose, Scene

#: While waiting for the daemon's first status, a stop is noticed this often, s.
WAIT_STEP = 0.1


class DaemonLayout:
    """The newest layout the daemon's status announces for ``scene`` (see the module).

    Args:
        scene: the scene the camera renders.
        key: the daemon's status key, ``legws/<robot>/status``.

    Attributes:
        layout: the pose of every object of the scene to render, ``None`` while there is
            none to render (:attr:`problem` says why).
        stage, decision: the daemon's stage and decision count of that layout.
        version: counts the changes of :attr:`layout` (and of :attr:`problem`).
    """

    def __init__(self, scene: Scene, key: str) -> None:
        self.scene = scene
        self.key = key
        self.watch = StatusWatch(key)
        self.layout: Layout | None = None
        self.problem: str | None = f"no status from the daemon on {key} yet"
        self.stage: str | None = None
        self.decision: int | None = None
        self.version = 0
        self._taken: StatusMessage | None = None

    def offer(self, payload: bytes) -> None:
        """A status payload as it arrived (zenoh's thread); one that does not validate is
        ignored."""
        self.watch.offer(payload)

    def update(self) -> bool:
        """Take up the newest status (the loop's thread); ``True`` when what to render
        changed (:attr:`layout` or :attr:`problem`)."""
        status = self.watch.newest
        if status is None or status is self._taken:
            return False
        self._taken = status
        layout, problem = self._layout_of(status)
        self.stage, self.decision = status.stage, status.decision
        if layout == self.layout and problem == self.problem:
            return False
        self.layout, self.problem = layout, problem
        self.version += 1
        return True

    def _layout_of(self, status: StatusMessage) -> tuple[Layout | None, str | None]:
        announced = status.layout
        if announced is None:
            return None, "the daemon's status carries no layout: nothing rendered"
        if announced.scene != self.scene.name:
            return None, (
                f"the daemon runs scene '{announced.scene}', the camera shows "
                f"'{self.scene.name}': nothing rendered"
            )
        unknown = [n for n in announced.objects if n not in self.scene.objects]
        if unknown:
            return None, (
                f"the daemon's layout names '{unknown[0]}', not an object of scene "
                f"'{self.scene.name}': nothing rendered"
            )
        poses = self.scene.poses()  # objects it leaves out stand as in the scene file
        for name, p in announced.objects.items():
            poses[name] = ObjectPose(p.x, p.y, p.yaw)
        return poses, None

    def wait(
        self,
        timeout: float,
        where: Sequence[str],
        stop: threading.Event | None = None,
        note: Callable[[str], None] | None = None,
    ) -> Layout | None:
        """The daemon's first layout, waited for up to ``timeout`` s (``None``: ``stop`` was
        set meanwhile).

        Args:
            where: the endpoints the session dials (for the messages).
            note: told once, after :data:`~legws_daemon.joystick.daemon_status.STATUS_NOTE`
                s without a status, that it waits and where it looks.

        Raises:
            InputError: no status came (one line naming the key and the endpoints), or its
                layout does not fit the scene.
        """
        start = time.monotonic()
        dialled = ", ".join(where) if where else "the zenoh configuration's endpoints"
        while self.watch.newest is None:
            now = time.monotonic()
            left = start + timeout - now
            if stop is not None and stop.is_set():
                return None
            if note is not None and now - start >= STATUS_NOTE and left > 0:
                note(
                    f"waiting up to {timeout:g} s for the daemon's status (its layout) on "
                    f"{self.key} (dialled {dialled})"
                )
                note = None
            if left <= 0:
                raise InputError(
                    f"no status from the daemon on {self.key} within {timeout:g} s (dialled "
                    f"{dialled}): is it running, for this robot, listening there? (without a "
                    "daemon: --layout-from scene renders the scene file's layout)"
                )
            self.watch.wait_first(min(left, WAIT_STEP))
        self.update()
        if self.layout is None:
            raise InputError(self.problem or "no layout from the daemon", source=self.key)
        return self.layout
