"""Camera frames to PNG files that appear whole or not at all. No ROS.

Each file is encoded in memory, written to a hidden temporary file in the target directory,
flushed to disk and renamed over its final name (``os.replace`` is atomic on POSIX), so a
reader never sees a partial PNG. Depth is stored as REP 118 16-bit millimetres: 0 where there
is no return (nan, inf, <= 0) or the value does not fit in 16 bits.
"""

import os
import tempfile

import cv2
import numpy as np

_PNG_OPTIONS = [cv2.IMWRITE_PNG_COMPRESSION, 1]  # fast; PNG stays lossless at every level
_MAX_MM = np.iinfo(np.uint16).max


def depth_to_mm(depth: np.ndarray) -> np.ndarray:
    """Return metres as uint16 millimetres, 0 for no return or out of range."""
    with np.errstate(invalid='ignore'):
        mm = np.rint(depth.astype(np.float64) * 1000.0)
        valid = np.isfinite(mm) & (mm > 0) & (mm <= _MAX_MM)
    return np.where(valid, mm, 0).astype(np.uint16)


def frame_name(sec: int, nanosec: int) -> str:
    """Return the file name stem of a frame stamped ``sec``.``nanosec`` (sorts by time)."""
    return f'frame_{sec:010d}_{nanosec:09d}'


def write_png(path: str, image: np.ndarray) -> None:
    """Write a PNG atomically: the file appears complete or not at all (OSError on failure)."""
    ok, encoded = cv2.imencode('.png', image, _PNG_OPTIONS)
    if not ok:
        raise OSError(f'PNG encoding of a {image.dtype} {image.shape} image failed')
    directory, name = os.path.split(path)
    fd, temporary = tempfile.mkstemp(prefix=f'.{name}.', suffix='.tmp', dir=directory or '.')
    try:
        with os.fdopen(fd, 'wb') as file:
            file.write(encoded.tobytes())
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except BaseException:
        _remove(temporary)
        raise


def save_frame(directory: str, sec: int, nanosec: int, rgb: np.ndarray,
               depth: np.ndarray | None) -> list[str]:
    """Save an RGB frame and its depth (metres, optional) as PNGs; return the paths written.

    Creates ``directory`` if needed. On OSError nothing of this frame is left behind.
    """
    os.makedirs(directory, exist_ok=True)
    stem = os.path.join(directory, frame_name(sec, nanosec))
    images = [(f'{stem}_color.png', cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))]
    if depth is not None:
        images.append((f'{stem}_depth.png', depth_to_mm(depth)))
    written: list[str] = []
    try:
        for path, image in images:
            write_png(path, image)
            written.append(path)
    except OSError:
        for path in written:
            _remove(path)
        raise
    return written


def _remove(path: str) -> None:
    """Delete a file if it exists; cleanup after a failure must not hide that failure."""
    try:
        os.unlink(path)
    except OSError:
        pass
