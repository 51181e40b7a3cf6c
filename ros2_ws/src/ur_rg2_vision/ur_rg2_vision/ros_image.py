"""sensor_msgs Image and CameraInfo to and from numpy, without cv_bridge.

Every reader checks the message against its own size fields (row ``step`` padding is allowed,
short data is not) and raises ValueError with a one-line reason for anything it cannot read.
"""

import numpy as np
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header

# encoding -> (channels, order of the R, G, B channels in a pixel)
_COLOR_ENCODINGS = {
    'rgb8': (3, [0, 1, 2]),
    'bgr8': (3, [2, 1, 0]),
    'rgba8': (4, [0, 1, 2]),
    'bgra8': (4, [2, 1, 0]),
}
# REP 118 depth encodings -> (dtype, metres per unit)
_DEPTH_ENCODINGS = {
    '32FC1': (np.dtype(np.float32), 1.0),
    '16UC1': (np.dtype(np.uint16), 0.001),
}


def _pixels(msg: Image, dtype: np.dtype, channels: int) -> np.ndarray:
    """Return the (height, width, channels) array of ``msg``, a view of its data."""
    height, width, step = msg.height, msg.width, msg.step
    row_bytes = width * channels * dtype.itemsize
    if height == 0 or width == 0:
        raise ValueError(f'empty {msg.encoding} image ({width}x{height})')
    if step < row_bytes:
        raise ValueError(f'{msg.encoding} image step {step} < {row_bytes} bytes for '
                         f'width {width}')
    if len(msg.data) < step * height:
        raise ValueError(f'{msg.encoding} image data has {len(msg.data)} bytes, '
                         f'{step * height} expected for {width}x{height} with step {step}')
    rows = np.frombuffer(msg.data, np.uint8, count=step * height).reshape(height, step)
    order = '>' if msg.is_bigendian else '<'
    return rows[:, :row_bytes].view(dtype.newbyteorder(order)).reshape(height, width, channels)


def image_to_rgb(msg: Image) -> np.ndarray:
    """Return a colour image message as a contiguous (H, W, 3) uint8 RGB array."""
    if msg.encoding not in _COLOR_ENCODINGS:
        raise ValueError(f'unsupported colour encoding {msg.encoding!r} '
                         f'(supported: {", ".join(_COLOR_ENCODINGS)})')
    channels, order = _COLOR_ENCODINGS[msg.encoding]
    pixels = _pixels(msg, np.dtype(np.uint8), channels)
    if order == [0, 1, 2] and channels == 3:
        return np.ascontiguousarray(pixels)
    return np.ascontiguousarray(pixels[:, :, order])


def image_to_depth(msg: Image) -> np.ndarray:
    """Return a depth image message as an (H, W) float32 array in metres (nan: no return)."""
    if msg.encoding not in _DEPTH_ENCODINGS:
        raise ValueError(f'unsupported depth encoding {msg.encoding!r} '
                         f'(supported: {", ".join(_DEPTH_ENCODINGS)})')
    dtype, scale = _DEPTH_ENCODINGS[msg.encoding]
    raw = _pixels(msg, dtype, 1)[:, :, 0]
    if dtype == np.float32:
        return raw.astype(np.float32)  # native byte order, owned copy
    depth = raw.astype(np.float32) * np.float32(scale)
    depth[raw == 0] = np.nan
    return depth


def rgb_to_image(rgb: np.ndarray, header: Header) -> Image:
    """Return an ``rgb8`` Image message of an (H, W, 3) uint8 array."""
    height, width = rgb.shape[:2]
    return Image(header=header, height=height, width=width, encoding='rgb8', is_bigendian=0,
                 step=width * 3, data=np.ascontiguousarray(rgb).tobytes())


def camera_matrix(info: CameraInfo) -> np.ndarray:
    """Return the 3x3 camera matrix ``k`` of a CameraInfo; ValueError if it is unusable."""
    k = np.asarray(info.k, dtype=np.float64).reshape(3, 3)
    if not (np.isfinite(k).all() and k[0, 0] > 0 and k[1, 1] > 0):
        raise ValueError(f'camera_info k has no positive finite focal lengths: {k.ravel()}')
    return k
