"""Web side of the 3D view: the scene's state as JSON, the robot's URDF and meshes, the page.

No ROS here: the node (``view3d_node``) fills a :class:`Scene` from its callbacks; tests drive
it directly. The page (``web/index.html``, ``web/view3d.js``) draws with three.js and
urdf-loader (vendored, ``web/vendor/PROVENANCE.md``) and polls:

``/scene`` the joint positions, gripper opening, ball (true and detected), camera pose and
intrinsics, last pick, all in ``world``; ``/cloud`` the depth camera's points (downsampled, in
``world``, with their colours); ``/robot.urdf`` the robot description with each mesh renamed
``mesh/N.ext``; ``/mesh/N.ext`` the Nth mesh file the description names (no other file is
served); ``/vendor/...`` the vendored modules; ``/favicon.ico`` the camera viewer's icon.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Sequence
import importlib.resources
import math
from pathlib import Path
import threading
import time
from typing import Any
from urllib.parse import unquote, urlparse
import xml.etree.ElementTree as ET

from aiohttp import web
from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
import numpy as np
from ur_rg2_vision.viewer_web import ViewerServer, favicon

WEB = importlib.resources.files(__package__).joinpath('web')
MESH_TYPES = {'.obj': 'text/plain', '.stl': 'model/stl', '.dae': 'model/vnd.collada+xml'}


def mesh_path(uri: str) -> Path | None:
    """Return the local file a URDF mesh ``filename`` names (file:// or package://), or None."""
    parsed = urlparse(uri)
    if parsed.scheme == 'file':
        path = Path(unquote(parsed.path))
    elif parsed.scheme == 'package':
        try:
            path = Path(get_package_share_directory(parsed.netloc)) / unquote(parsed.path)[1:]
        except (PackageNotFoundError, ValueError, OSError):
            return None
    elif parsed.scheme == '' and uri.startswith('/'):
        path = Path(uri)
    else:
        return None
    return path if path.suffix.lower() in MESH_TYPES else None


def served_description(urdf: str) -> tuple[str, dict[str, Path]]:
    """Return the URDF with its meshes renamed ``mesh/N.ext``, and those names' files.

    Raises ValueError for text that is not XML. A mesh that names no local file of a known
    type is left out of the description (its link is drawn without it).
    """
    try:
        root = ET.fromstring(urdf)
    except ET.ParseError as error:
        raise ValueError(f'robot_description is not XML: {error}') from None
    files: dict[str, Path] = {}
    by_path: dict[Path, str] = {}
    for geometry in root.iter('geometry'):
        for mesh in geometry.findall('mesh'):
            path = mesh_path(mesh.get('filename', ''))
            if path is None:
                geometry.remove(mesh)
                continue
            if path not in by_path:
                by_path[path] = f'{len(by_path)}{path.suffix.lower()}'
                files[by_path[path]] = path
            mesh.set('filename', f'mesh/{by_path[path]}')
    return ET.tostring(root, encoding='unicode'), files


def finite(values, digits: int = 4) -> list[float] | None:
    """Return ``values`` rounded for JSON, or None when one is not finite."""
    values = [float(v) for v in values]
    return [round(v, digits) for v in values] if all(map(math.isfinite, values)) else None


class Scene:
    """The latest state of the scene, set from ROS threads, read by the web server.

    ``refresh`` is called before each ``/scene`` document is made (the node brings the
    entries up to date then), ``cloud`` for each ``/cloud``.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._state: dict[str, tuple[Any, float]] = {}
        self._description: tuple[str, dict[str, Path]] | None = None
        self.refresh: Callable[[], None] = lambda: None
        self.cloud: Callable[[], dict[str, Any] | None] = lambda: None

    def set(self, key: str, value: Any, stamp: float | None = None) -> None:
        """Set one entry of the ``/scene`` document (JSON-able).

        ``stamp``: when its value came (``time.monotonic()``), now by default; its age counts
        from then.
        """
        with self._lock:
            self._state[key] = (value, time.monotonic() if stamp is None else stamp)

    def set_description(self, urdf: str) -> int:
        """Take a new robot description; return how many mesh files it names (ValueError)."""
        description = served_description(urdf)
        with self._lock:
            self._description = description
            self._state['description'] = (len(urdf), time.monotonic())
        return len(description[1])

    def document(self) -> dict[str, Any]:
        """Return the ``/scene`` document: the entries and their ages in seconds."""
        now = time.monotonic()
        with self._lock:
            entries = dict(self._state)
        document = {key: value for key, (value, _) in entries.items()}
        document['ages'] = {key: round(now - stamp, 3) for key, (_, stamp) in entries.items()}
        return document

    def description(self) -> tuple[str, dict[str, Path]] | None:
        """Return the served URDF and its mesh files, None before one came."""
        with self._lock:
            return self._description


SCENE = web.AppKey('scene', Scene)
_NO_CACHE = {'Cache-Control': 'no-store'}


async def _page(request: web.Request) -> web.Response:
    name = request.match_info.get('name', 'index.html')
    content_type = 'text/html' if name.endswith('.html') else 'text/javascript'
    return web.Response(text=WEB.joinpath(name).read_text('utf-8'), content_type=content_type,
                        headers={'Cache-Control': 'no-cache'})


async def _scene(request: web.Request) -> web.Response:
    scene = request.app[SCENE]
    # Off the event loop: it takes and reads what came since the last request.
    await asyncio.get_running_loop().run_in_executor(None, scene.refresh)
    return web.json_response(scene.document(), headers=_NO_CACHE)


async def _cloud(request: web.Request) -> web.Response:
    # Off the event loop: it decodes a depth image and projects its points.
    cloud = await asyncio.get_running_loop().run_in_executor(None, request.app[SCENE].cloud)
    if cloud is None:
        raise web.HTTPServiceUnavailable(text='no depth image and camera_info yet\n')
    response = web.json_response(cloud, headers=_NO_CACHE)
    response.enable_compression()
    return response


async def _urdf(request: web.Request) -> web.Response:
    description = request.app[SCENE].description()
    if description is None:
        raise web.HTTPServiceUnavailable(text='no robot_description received yet\n')
    return web.Response(text=description[0], content_type='application/xml', headers=_NO_CACHE)


async def _mesh(request: web.Request) -> web.StreamResponse:
    description = request.app[SCENE].description()
    path = description[1].get(request.match_info['name']) if description else None
    if path is None or not path.is_file():
        raise web.HTTPNotFound(text='no such mesh in robot_description\n')
    response = web.FileResponse(path, headers={'Content-Type': MESH_TYPES[path.suffix.lower()]})
    response.enable_compression()
    return response


def create_app(scene: Scene) -> web.Application:
    """Return the 3D view's aiohttp application serving ``scene``; other paths answer 404."""
    app = web.Application()
    app[SCENE] = scene
    app.add_routes([
        web.get('/', _page),
        web.get(r'/{name:view3d\.js}', _page),
        web.get('/scene', _scene),
        web.get('/cloud', _cloud),
        web.get('/robot.urdf', _urdf),
        web.get(r'/mesh/{name:[0-9]+\.[a-z]+}', _mesh),
        web.get('/favicon.ico', favicon),
    ])
    # aiohttp's static route refuses paths that leave the directory, and symbolic links.
    app.router.add_static('/vendor', Path(str(WEB.joinpath('vendor'))))
    return app


class View3dServer(ViewerServer):
    """Serves :func:`create_app` on a thread of its own (the camera viewer's server)."""

    create_app = staticmethod(create_app)


def depth_cloud(depth: np.ndarray, k: Sequence[float], world_from_camera: np.ndarray,
                step: int, rgb: np.ndarray | None = None,
                max_range: float = 10.0) -> dict[str, list]:
    """Return every ``step``-th pixel's point of a depth image in the world, with its colour.

    ``depth`` (H×W, metres along the optical z axis, REP 118), ``k`` the row-major 3×3 camera
    matrix, ``world_from_camera`` the optical frame's 4×4 pose in the world, ``rgb`` (H×W×3)
    the registered colour image or None. Pixels with no return (inf, NaN, 0) are left out.
    """
    fx, cx, fy, cy = k[0], k[2], k[4], k[5]
    rows, cols = np.mgrid[0:depth.shape[0]:step, 0:depth.shape[1]:step]
    z = depth[rows, cols].astype(np.float64)
    valid = np.isfinite(z) & (z > 0) & (z < max_range)
    u, v, z = cols[valid], rows[valid], z[valid]
    camera = np.stack([(u - cx) * z / fx, (v - cy) * z / fy, z, np.ones_like(z)])
    points = (world_from_camera @ camera)[:3].T
    colors = (rgb[v, u] if rgb is not None and rgb.shape[:2] == depth.shape
              else np.full((len(z), 3), 200, np.uint8))
    return {'points': np.round(points, 3).ravel().tolist(),
            'colors': colors.astype(np.uint8).ravel().tolist()}
