"""Draws camera frames on a thread of its own, so that the physics never waits for one.

The simulation thread takes a snapshot of the shapes' poses (a fraction of a millisecond) and
hands it over with its stamp; this thread draws it with OpenGL and delivers the frame. One
frame is drawn at a time: a frame due while the last one is still being drawn is dropped and
counted, so a slow machine loses camera frames before it loses physics steps or joint states.
Plain Python, no ROS.
"""

from collections import deque
from collections.abc import Callable
import threading
from typing import Optional

from ur_rg2_sim.camera import Camera, Frame
from ur_rg2_sim.gl_renderer import release_thread_context
from ur_rg2_sim.render_scene import SceneSnapshot

Deliver = Callable[[int, Camera, Frame], None]


class DropWatch:
    """Tells a camera that drops a frame now and then from one that cannot keep its rate.

    :meth:`dropped` answers True once: when the frames dropped over the last ``window_s`` of
    simulation time reach ``share`` of the frames due in it.
    """

    def __init__(self, window_s: float = 5.0, share: float = 0.5) -> None:
        self._window_ns = round(window_s * 1e9)
        self._share = share
        self._stamps: deque[int] = deque()
        self.told = False

    def dropped(self, stamp_ns: int, rate_hz: float) -> bool:
        """Count a dropped frame; return True the first time the drops are sustained."""
        self._stamps.append(stamp_ns)
        while self._stamps[0] <= stamp_ns - self._window_ns:
            self._stamps.popleft()
        sustained = len(self._stamps) >= self._share * rate_hz * self._window_ns / 1e9
        if sustained and not self.told:
            self.told = True
            return True
        return False


class RenderThread:
    """Draws one snapshot at a time and hands each frame to ``deliver`` (on this thread)."""

    def __init__(self, deliver: Deliver) -> None:
        self._deliver = deliver
        self._condition = threading.Condition()
        self._job: Optional[tuple[Optional[int], Camera, SceneSnapshot]] = None
        self._busy = False
        self._stop = False
        self.error: Optional[BaseException] = None  # what stopped the thread, if anything
        self.drawn = 0
        self._thread = threading.Thread(target=self._run, name='camera', daemon=True)
        self._thread.start()

    def submit(self, stamp_ns: int, camera: Camera, snapshot: SceneSnapshot) -> bool:
        """Queue a snapshot to draw; return False (the frame is dropped) while one is drawn."""
        with self._condition:
            if self._busy or self._job is not None or self._stop:
                return False
            self._job = (stamp_ns, camera, snapshot)
            self._condition.notify_all()
            return True

    def warm_up(self, camera: Camera, snapshot: SceneSnapshot, timeout: float = 30.0) -> None:
        """Draw a frame and deliver none: the first draw builds the context and the meshes."""
        with self._condition:
            self._condition.wait_for(lambda: self._job is None, timeout)
            self._job = (None, camera, snapshot)
            self._condition.notify_all()
        self.wait_idle(timeout)

    def wait_idle(self, timeout: Optional[float] = None) -> bool:
        """Wait until no frame is being drawn; return whether that happened in time."""
        with self._condition:
            return self._condition.wait_for(
                lambda: not (self._busy or self._job is not None) or self._stop, timeout)

    def stop(self, timeout: float = 5.0) -> bool:
        """Stop after the frame being drawn; return whether the thread ended in time."""
        with self._condition:
            self._stop = True
            self._condition.notify_all()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout)
        return not self._thread.is_alive()

    def _run(self) -> None:
        drawing_for: Optional[Camera] = None
        try:
            while True:
                with self._condition:
                    self._condition.wait_for(lambda: self._job is not None or self._stop)
                    if self._stop:
                        return
                    (stamp_ns, camera, snapshot), self._job = self._job, None
                    self._busy = True
                if camera is not drawing_for:
                    # A new camera (new size or pose): free the old one's context here, where
                    # it was made current.
                    if drawing_for is not None:
                        drawing_for.close()
                    drawing_for = camera
                frame = camera.draw(snapshot)
                if stamp_ns is not None:
                    self._deliver(stamp_ns, camera, frame)
                with self._condition:
                    self.drawn += stamp_ns is not None
                    self._busy = False
                    self._condition.notify_all()
        except BaseException as error:  # noqa: B036 - reported through the simulation loop
            self.error = error
        finally:
            if drawing_for is not None:
                drawing_for.close()
                release_thread_context()
            with self._condition:
                self._stop = True
                self._busy = False
                self._condition.notify_all()
