"""Web side of the browser viewer: a frame and state hub plus the aiohttp app serving it.

No ROS here: the node (``viewer_node``) feeds a :class:`FrameHub` from its callbacks and runs a
:class:`ViewerServer`; tests drive both directly.

Routes: ``/`` the page, ``/state`` JSON for the page, ``/stream`` MJPEG
(``multipart/x-mixed-replace``, like ROS's web_video_server), ``/snapshot`` one JPEG,
``/favicon.ico`` the tab's icon.
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable, Sequence
import importlib.resources
import ipaddress
import math
import threading
import time
from typing import Any

from aiohttp import web
import cv2
import numpy as np

BOUNDARY = 'frame'
GRIPPER_PREFIX = 'rg2_'
PAGE = importlib.resources.files(__package__).joinpath('web', 'index.html').read_text('utf-8')
# How often a stream looks for a new frame when frames are taken only when asked, s.
FRAME_PULL_PERIOD_S = 0.01
# The tab's icon, the ball: browsers ask for /favicon.ico whatever a page says.
FAVICON = ('<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 16 16">'
           '<circle cx="8" cy="8" r="7" fill="#d62020"/></svg>')


def encode_jpeg(rgb: np.ndarray, quality: int) -> bytes:
    """Return ``rgb`` (H×W×3, uint8, RGB order) as JPEG bytes."""
    ok, buffer = cv2.imencode('.jpg', cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR),
                              [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError(f'OpenCV could not encode a {rgb.shape} image as JPEG')
    return buffer.tobytes()


def finite_or_none(value: float) -> float | None:
    """Return ``value``, or ``None`` for NaN/inf, which JSON (and the browser) cannot parse."""
    return value if math.isfinite(value) else None


def joint_summary(names: Sequence[str], positions: Sequence[float]) -> dict[str, Any]:
    """Summarise a joint state for the page: arm joints in degrees, the gripper's opening in mm.

    The sim models the RG2 as two prismatic ``rg2_*`` finger joints, each at half the opening
    between the pads (in m), so the opening is their sum. The raw ``rg2_*`` positions are kept
    as well.
    """
    arm, gripper = [], []
    for name, position in zip(names, positions, strict=True):
        if name.startswith(GRIPPER_PREFIX):
            gripper.append({'name': name, 'position': finite_or_none(position)})
        else:
            arm.append({'name': name, 'deg': finite_or_none(math.degrees(position))})
    fingers = [joint['position'] for joint in gripper]
    opening_mm = 1000.0 * sum(fingers) if fingers and None not in fingers else None
    return {'joints': arm, 'gripper': {'joints': gripper, 'opening_mm': opening_mm}}


def ball_summary(frame_id: str, point: Sequence[float],
                 to_world: Callable[[Sequence[float]], Sequence[float]] | None,
                 to_base_link: Callable[[Sequence[float]], Sequence[float]] | None = None,
                 via: str = "from the sim's camera pose") -> dict[str, Any]:
    """Summarise a ball position for the page: in its own frame, the world and base_link.

    ``to_world`` and ``to_base_link`` convert a point of ``frame_id`` to those frames; ``None``
    when that is not known (yet), and then ``world`` or ``base_link`` is ``None``. ``via``
    says where the conversion comes from (the transform tree, or the sim's camera pose).
    """
    x, y, z = (finite_or_none(value) for value in point)
    summary = {'frame_id': frame_id, 'x': x, 'y': y, 'z': z}
    for name, convert in (('world', to_world), ('base_link', to_base_link)):
        summary[name] = None
        if convert is not None and None not in (x, y, z):
            cx, cy, cz = (finite_or_none(float(value)) for value in convert(point))
            summary[name] = {'frame_id': name, 'x': cx, 'y': cy, 'z': cz}
    summary['via'] = via if summary['world'] or summary['base_link'] else None
    return summary


class FrameHub:
    """Latest camera frame and robot state, handed from ROS threads to the web server.

    ``put_frame`` and ``set_state`` may be called from any thread. Each new frame is decoded
    (``decode``) and JPEG-encoded at most once, lazily, the first time a client asks for it,
    and the same bytes go to every client; frames nobody asked for are never decoded. A slow
    client simply skips to the newest frame, so nothing queues up behind it. ``refresh`` is
    called before each ``/state`` document is made (the node brings the entries up to date).
    ``pull_frames``, when set, puts the newest frame: frames are then taken only when asked
    for (``/state``, ``/snapshot``, and every ``FRAME_PULL_PERIOD_S`` while a stream is open).
    """

    def __init__(self, jpeg_quality: int = 80,
                 decode: Callable[[Any], np.ndarray | None] | None = None) -> None:
        """``decode`` makes a put frame an RGB array (None: it cannot); by default it is one."""
        self.jpeg_quality = jpeg_quality
        self.viewers = 0  # /stream clients connected now (written on the loop only)
        self.refresh: Callable[[], None] = lambda: None
        self.pull_frames: Callable[[], object] | None = None
        self._decode = decode or (lambda frame: frame)
        self._decoded: tuple[int, np.ndarray | None] | None = None  # (seq, the newest decoded)
        self._decoding = threading.Lock()
        self._lock = threading.Lock()
        self._frame: Any = None
        self._seq = 0  # frames so far
        self._published: int | None = None  # the publisher's count of the latest frame
        # (monotonic time, frames so far) of the latest frames put, for the frame rate
        self._arrivals: deque[tuple[float, int]] = deque(maxlen=31)
        self._state: dict[str, tuple[Any, float]] = {}  # key: (value, monotonic time set)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._wakeup: asyncio.Event | None = None
        self._jpeg: tuple[int, asyncio.Future[bytes | None]] | None = None
        self._closed = False

    def put_frame(self, frame: Any, received: float | None = None,
                  sequence: int | None = None) -> None:
        """Make ``frame`` the latest; it must not be modified later.

        An RGB array (H×W×3 uint8), or what the hub's ``decode`` makes one of. ``received``:
        when it came (``time.monotonic()``), now by default. ``sequence``: its publisher's count
        of frames; the frames it skipped since the latest count as come.
        """
        with self._lock:
            skipped = 0
            if sequence is not None and self._published is not None:
                skipped = max(0, sequence - self._published - 1)
            self._published = sequence
            self._frame = frame
            self._seq += 1 + skipped
            self._arrivals.append((time.monotonic() if received is None else received,
                                   self._seq))
            loop = self._loop
        # Only streams wait for frames; one that starts now takes this frame without a wakeup
        # (its viewer is counted before it looks at the frame).
        if loop is not None and self.viewers:
            try:
                loop.call_soon_threadsafe(self._notify)
            except RuntimeError:  # the loop closed under us: the server is stopping
                pass

    def set_state(self, key: str, value: Any, stamp: float | None = None) -> None:
        """Set one top-level entry of the ``/state`` document (``value`` must be JSON-able).

        ``stamp``: when its value came (``time.monotonic()``), now by default; its age counts
        from then.
        """
        with self._lock:
            self._state[key] = (value, time.monotonic() if stamp is None else stamp)

    def state(self) -> dict[str, Any]:
        """Return the ``/state`` document.

        It holds the entries set so far, ``ages`` (seconds since each entry was set),
        ``camera`` statistics and the number of stream ``viewers``.
        """
        self.refresh()
        if self.pull_frames is not None:
            self.pull_frames()
        with self._lock:
            entries = dict(self._state)
            frame, seq, arrivals = self._frame, self._seq, list(self._arrivals)
        frame = None if frame is None else self._rgb(seq, frame)
        now = time.monotonic()
        state = {key: value for key, (value, _) in entries.items()}
        state['ages'] = {key: now - stamp for key, (_, stamp) in entries.items()}
        fps = None
        if len(arrivals) >= 2 and now - arrivals[-1][0] < 2.0:
            (first, first_seq), (last, last_seq) = arrivals[0], arrivals[-1]
            fps = (last_seq - first_seq) / (last - first) if last > first else None
        state['camera'] = {
            'frames': seq,
            'fps': fps,
            'age_s': now - arrivals[-1][0] if arrivals else None,
            'width': None if frame is None else frame.shape[1],
            'height': None if frame is None else frame.shape[0],
        }
        state['viewers'] = self.viewers
        return state

    def attach(self, loop: asyncio.AbstractEventLoop) -> None:
        """Deliver new-frame wake-ups to ``loop`` (call on that loop)."""
        self._wakeup = asyncio.Event()
        with self._lock:
            self._loop = loop

    def close(self) -> None:
        """Wake and end every stream (call on the loop)."""
        self._closed = True
        with self._lock:
            self._loop = None
        if self._wakeup is not None:
            self._wakeup.set()

    def _notify(self) -> None:
        if self._wakeup is not None and not self._closed:
            # Waiters hold the old event; a fresh one is ready for the next frame.
            fired, self._wakeup = self._wakeup, asyncio.Event()
            fired.set()

    async def next_jpeg(self, after: int) -> tuple[int, bytes] | None:
        """Wait for a frame newer than sequence number ``after``; ``None`` once closed."""
        while not self._closed:
            if self.pull_frames is not None:
                self.pull_frames()
            with self._lock:
                seq, frame = self._seq, self._frame
            if seq > after and frame is not None:
                jpeg = await self._encoded(seq, frame)
                if jpeg is not None:
                    return seq, jpeg
                after = seq  # a frame that cannot be decoded: wait for the next
            if self.pull_frames is None:
                await self._wakeup.wait()
            else:
                await asyncio.sleep(FRAME_PULL_PERIOD_S)
        return None

    async def latest_jpeg(self) -> bytes | None:
        """Return the newest frame as JPEG, or ``None`` when no frame came yet."""
        if self.pull_frames is not None:
            self.pull_frames()
        with self._lock:
            seq, frame = self._seq, self._frame
        return None if frame is None else await self._encoded(seq, frame)

    def _rgb(self, seq: int, frame: Any) -> np.ndarray | None:
        """Return frame ``seq`` decoded (None: it cannot be), decoding it once."""
        with self._decoding:
            if self._decoded is None or self._decoded[0] != seq:
                self._decoded = (seq, self._decode(frame))
            return self._decoded[1]

    def _jpeg_of(self, seq: int, frame: Any) -> bytes | None:
        rgb = self._rgb(seq, frame)
        return None if rgb is None else encode_jpeg(rgb, self.jpeg_quality)

    async def _encoded(self, seq: int, frame: Any) -> bytes | None:
        if self._jpeg is None or self._jpeg[0] != seq:
            # Decode and encode off the event loop so streaming and /state stay responsive.
            future = asyncio.get_running_loop().run_in_executor(
                None, self._jpeg_of, seq, frame)
            self._jpeg = (seq, future)
        # Shielded: one client going away must not cancel the encoding the others await.
        return await asyncio.shield(self._jpeg[1])


HUB = web.AppKey('hub', FrameHub)


async def _index(request: web.Request) -> web.Response:
    return web.Response(text=PAGE, content_type='text/html', headers={'Cache-Control': 'no-cache'})


async def favicon(_request: web.Request) -> web.Response:
    """Answer ``/favicon.ico`` with the ball icon (the 3D view's page serves it too)."""
    return web.Response(text=FAVICON, content_type='image/svg+xml',
                        headers={'Cache-Control': 'max-age=86400'})


async def _state(request: web.Request) -> web.Response:
    # Off the event loop: it takes what came since the last request, and may decode a frame.
    state = await asyncio.get_running_loop().run_in_executor(None, request.app[HUB].state)
    return web.json_response(state, headers={'Cache-Control': 'no-store'})


async def _snapshot(request: web.Request) -> web.Response:
    jpeg = await request.app[HUB].latest_jpeg()
    if jpeg is None:
        raise web.HTTPServiceUnavailable(text='no camera frame received yet\n')
    return web.Response(body=jpeg, content_type='image/jpeg',
                        headers={'Cache-Control': 'no-store'})


async def _stream(request: web.Request) -> web.StreamResponse:
    hub = request.app[HUB]
    response = web.StreamResponse(headers={
        'Content-Type': f'multipart/x-mixed-replace;boundary={BOUNDARY}',
        'Cache-Control': 'no-store',
    })
    await response.prepare(request)
    hub.viewers += 1
    try:
        seq = 0
        # A client that goes away cancels this task (handler_cancellation) or makes a write
        # raise; either way the finally below runs and nothing is left waiting.
        while (frame := await hub.next_jpeg(seq)) is not None:
            seq, jpeg = frame
            await response.write(
                f'--{BOUNDARY}\r\nContent-Type: image/jpeg\r\n'
                f'Content-Length: {len(jpeg)}\r\n\r\n'.encode('ascii') + jpeg + b'\r\n')
    except ConnectionError:
        pass
    finally:
        hub.viewers -= 1
    return response


async def _attach(app: web.Application) -> None:
    app[HUB].attach(asyncio.get_running_loop())


async def _close(app: web.Application) -> None:
    app[HUB].close()


def create_app(hub: FrameHub) -> web.Application:
    """Return the viewer's aiohttp application serving ``hub``; other paths answer 404."""
    app = web.Application()
    app[HUB] = hub
    app.add_routes([
        web.get('/', _index),
        web.get('/state', _state),
        web.get('/stream', _stream, allow_head=False),  # HEAD would hold a stream task open
        web.get('/snapshot', _snapshot),
        web.get('/favicon.ico', favicon),
    ])
    app.on_startup.append(_attach)
    app.on_shutdown.append(_close)
    return app


def is_loopback(address: str) -> bool:
    """Return whether ``address`` (an IP address or ``localhost``) is this host only."""
    try:
        return ipaddress.ip_address(address).is_loopback
    except ValueError:
        return address == 'localhost'


class ViewerServer:
    """Runs :func:`create_app` on its own thread and event loop, so ROS callbacks never wait.

    A page of another app (the 3D view's) subclasses it with its own ``create_app``.
    """

    create_app = staticmethod(create_app)

    def __init__(self, hub: FrameHub, address: str = '127.0.0.1', port: int = 8080) -> None:
        self.hub = hub
        self.address = address
        self.port = port  # the bound port once started (useful with port 0)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._runner: web.AppRunner | None = None

    @property
    def url(self) -> str:
        """Address of the page, for people and tests."""
        host = f'[{self.address}]' if ':' in self.address else self.address
        return f'http://{host}:{self.port}/'

    def start(self, timeout: float = 10.0) -> None:
        """Bind and start serving; raises ``OSError`` when the address cannot be bound."""
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name='viewer-http',
                                        daemon=True)
        self._thread.start()
        try:
            asyncio.run_coroutine_threadsafe(self._serve(), self._loop).result(timeout)
        except BaseException:
            self.stop()
            raise

    async def _serve(self) -> None:
        # handler_cancellation: a stream whose client disconnects is cancelled at once,
        # even while it waits for the next frame. access_log off: one line per request and
        # per /state poll would flood the terminal.
        self._runner = web.AppRunner(self.create_app(self.hub), handler_cancellation=True,
                                     access_log=None, shutdown_timeout=2.0)
        await self._runner.setup()
        await web.TCPSite(self._runner, self.address, self.port).start()
        self.port = self._runner.addresses[0][1]

    def stop(self, timeout: float = 10.0) -> None:
        """End every stream, close the socket and join the server thread (idempotent)."""
        if self._loop is None:
            return
        if self._runner is not None:
            asyncio.run_coroutine_threadsafe(self._runner.cleanup(), self._loop).result(timeout)
            self._runner = None
        # The JPEG encoder threads of run_in_executor: let a running encode finish.
        asyncio.run_coroutine_threadsafe(
            self._loop.shutdown_default_executor(), self._loop).result(timeout)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout)
        self._loop.close()
        self._loop = None
