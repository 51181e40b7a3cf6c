"""The viewer's HTTP side without ROS: FrameHub + ViewerServer on an ephemeral loopback port."""

import asyncio
import json
import math
import threading
import time
import urllib.error
import urllib.request

import aiohttp
from conftest import wait_for
import cv2
import numpy as np
import pytest
from ur_rg2_vision import viewer_web
from ur_rg2_vision.viewer_web import FrameHub, ViewerServer, ball_summary, joint_summary


def solid(value: int, width: int = 64, height: int = 48) -> np.ndarray:
    """Return an RGB frame whose red channel is ``value`` (green and blue fixed)."""
    frame = np.empty((height, width, 3), np.uint8)
    frame[...] = (value, 40, 200)
    return frame


def decode(jpeg: bytes) -> np.ndarray:
    """Return a JPEG as an RGB array."""
    bgr = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    assert bgr is not None, 'not a JPEG'
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


class Camera:
    """Feeds the hub a new frame (red channel counting up) every 20 ms from its own thread.

    ``times``: when each frame came (``time.monotonic()``), as the hub is told.
    """

    def __init__(self, hub: FrameHub) -> None:
        self.hub = hub
        self.sent = 0
        self.times: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(0.02):
            self.sent += 1
            self.times.append(time.monotonic())
            self.hub.put_frame(solid(self.sent * 5 % 256), received=self.times[-1])

    def __enter__(self) -> 'Camera':
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


@pytest.fixture
def server():
    srv = ViewerServer(FrameHub(), '127.0.0.1', 0)
    srv.start()
    try:
        yield srv
    finally:
        srv.stop()


def get(url: str) -> tuple[int, str, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=10) as response:
            return response.status, response.headers['Content-Type'], response.read()
    except urllib.error.HTTPError as error:
        return error.code, error.headers['Content-Type'], error.read()


async def read_stream(url: str, count: int) -> tuple[str, list[bytes]]:
    """Read ``count`` JPEG parts from the MJPEG stream at ``url``; return (content type, parts)."""
    async with aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=20)) as session:
        async with session.get(url) as response:
            reader = aiohttp.MultipartReader.from_response(response)
            parts = []
            while len(parts) < count:
                part = await reader.next()
                assert part.headers['Content-Type'] == 'image/jpeg'
                parts.append(await part.read())
            return response.headers['Content-Type'], parts


def test_unknown_paths_are_404(server):
    for path in ('nope', 'stream/x', 'index.html', 'state/'):
        assert get(server.url + path)[0] == 404, path


def test_page_is_served_on_loopback(server):
    status, content_type, body = get(server.url)
    assert status == 200 and content_type.startswith('text/html')
    assert b'id="stream"' in body and b"fetch('state'" in body
    assert server.address == '127.0.0.1' and server.url.startswith('http://127.0.0.1:')


def test_the_tab_icon_is_served(server):
    status, content_type, body = get(server.url + 'favicon.ico')
    assert status == 200 and content_type.startswith('image/svg+xml')
    assert body.startswith(b'<svg') and b'<circle' in body


def test_snapshot_is_the_latest_frame_as_jpeg(server):
    status, _, body = get(server.url + 'snapshot')
    assert status == 503 and b'no camera frame' in body
    server.hub.put_frame(solid(10))
    server.hub.put_frame(solid(230))
    status, content_type, body = get(server.url + 'snapshot')
    assert status == 200 and content_type == 'image/jpeg'
    image = decode(body)
    assert image.shape == (48, 64, 3)
    assert np.abs(image.astype(int) - solid(230)).max() <= 8


def test_stream_sends_new_frames_encoded_once_for_all_clients(server, monkeypatch):
    encoded = []
    encode = viewer_web.encode_jpeg

    def counting_encode(rgb, quality):
        encoded.append(int(rgb[0, 0, 0]))
        return encode(rgb, quality)

    monkeypatch.setattr(viewer_web, 'encode_jpeg', counting_encode)

    async def ten_clients():
        return await asyncio.gather(*(read_stream(server.url + 'stream', 8) for _ in range(10)))

    with Camera(server.hub) as camera:
        results = asyncio.run(ten_clients())
    for content_type, parts in results:
        assert content_type == f'multipart/x-mixed-replace;boundary={viewer_web.BOUNDARY}'
        reds = [int(decode(part)[0, 0, 0]) for part in parts]
        # Each part is a newer frame than the one before (the red channel counts up by 5).
        assert len(set(reds)) == len(reds), reds
    # One encoding per frame at most, however many clients watched it.
    assert len(encoded) == len(set(encoded)) <= camera.sent


def test_disconnect_mid_stream_leaves_nothing_behind(server):
    hub = server.hub

    async def watch_then_leave():
        async with aiohttp.ClientSession() as session:
            response = await session.get(server.url + 'stream')
            reader = aiohttp.MultipartReader.from_response(response)
            await (await reader.next()).read()
            wait_for(lambda: hub.viewers == 1, 5, 'the stream to count its viewer')
            response.close()  # drop the connection without reading the rest

    with Camera(hub):
        asyncio.run(watch_then_leave())
    wait_for(lambda: hub.viewers == 0, 5, 'the stream handler to end after the client left')

    # Disconnect while the handler waits for a frame that never comes (camera stopped).
    hub.put_frame(solid(1))
    asyncio.run(watch_then_leave())
    wait_for(lambda: hub.viewers == 0, 5, 'the idle stream handler to end')

    async def handler_tasks():
        return [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]

    assert asyncio.run_coroutine_threadsafe(handler_tasks(), server._loop).result(5) == []


def test_stop_ends_open_streams(server):
    server.hub.put_frame(solid(1))
    ended = threading.Event()

    async def watch():
        async with aiohttp.ClientSession() as session:
            async with session.get(server.url + 'stream') as response:
                async for _ in response.content.iter_any():
                    pass
        ended.set()

    client = threading.Thread(target=asyncio.run, args=(watch(),), daemon=True)
    client.start()
    wait_for(lambda: server.hub.viewers == 1, 5, 'the client to connect')
    started = time.monotonic()
    server.stop()
    assert time.monotonic() - started < 2.0
    wait_for(ended.is_set, 5, 'the client to see the end of the stream')
    client.join(5)


def test_state_is_json_with_degrees_gripper_ball_and_camera(server):
    hub = server.hub
    status, content_type, body = get(server.url + 'state')
    assert status == 200 and content_type.startswith('application/json')
    assert json.loads(body)['camera'] == {'frames': 0, 'fps': None, 'age_s': None,
                                          'width': None, 'height': None}

    names = ['shoulder_pan_joint', 'elbow_joint', 'rg2_left_finger_joint',
             'rg2_right_finger_joint']
    for key, value in joint_summary(names, [math.pi / 2, -0.5, 0.02, 0.021]).items():
        hub.set_state(key, value)
    hub.set_state('ball', {'frame_id': 'camera_color_optical_frame', 'x': 0.1, 'y': -0.05,
                           'z': 1.2})
    with Camera(hub) as fed:
        wait_for(lambda: hub.state()['camera']['fps'], 5, 'a camera frame rate')
    state = json.loads(get(server.url + 'state')[2])
    assert state['joints'] == [{'name': 'shoulder_pan_joint', 'deg': pytest.approx(90.0)},
                               {'name': 'elbow_joint', 'deg': pytest.approx(-28.6479, abs=1e-3)}]
    assert state['gripper'] == {
        'joints': [{'name': 'rg2_left_finger_joint', 'position': 0.02},
                   {'name': 'rg2_right_finger_joint', 'position': 0.021}],
        'opening_mm': pytest.approx(41.0)}
    assert state['ball']['z'] == 1.2
    assert 0 <= state['ages']['ball'] < 10
    camera = state['camera']
    assert camera['width'] == 64 and camera['height'] == 48 and camera['frames'] > 1
    # Over the frames it last received (at most 31): 50 Hz, or what a loaded machine fed.
    window = fed.times[-31:]
    assert camera['fps'] == pytest.approx((len(window) - 1) / (window[-1] - window[0]))
    assert state['viewers'] == 0


def test_joint_summary_splits_gripper_and_drops_non_finite():
    summary = joint_summary(['a', 'rg2_left', 'b'], [float('nan'), float('inf'), 0.0])
    assert summary['joints'] == [{'name': 'a', 'deg': None}, {'name': 'b', 'deg': 0.0}]
    assert summary['gripper'] == {'joints': [{'name': 'rg2_left', 'position': None}],
                                  'opening_mm': None}
    json.dumps(summary, allow_nan=False)


def test_busy_port_raises_oserror(server):
    second = ViewerServer(FrameHub(), '127.0.0.1', server.port)
    with pytest.raises(OSError):
        second.start()


def test_ball_summary_in_its_frame_and_the_world():
    shift = lambda point: [value + 1.0 for value in point]  # noqa: E731 - a toy transform
    assert ball_summary('cam', (0.1, 0.2, 1.5), shift) == {
        'frame_id': 'cam', 'x': 0.1, 'y': 0.2, 'z': 1.5,
        'world': {'frame_id': 'world', 'x': 1.1, 'y': 1.2, 'z': 2.5}, 'base_link': None,
        'via': "from the sim's camera pose"}
    assert ball_summary('cam', (0.1, 0.2, 1.5), None)['world'] is None
    assert ball_summary('cam', (0.1, 0.2, 1.5), None)['via'] is None
    both = ball_summary('cam', (0.1, 0.2, 1.5), shift, shift, 'through the transform tree')
    assert both['base_link'] == {'frame_id': 'base_link', 'x': 1.1, 'y': 1.2, 'z': 2.5}
    assert both['via'] == 'through the transform tree'
    unknown = ball_summary('cam', (math.nan, 0.2, 1.5), shift)
    assert unknown['x'] is None and unknown['world'] is None
