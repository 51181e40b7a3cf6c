"""Camera frames to PNG files that appear whole and never replace a file. No ROS.

A frame is saved as ``frame_<UTC date and time of the save>_sim<stamp>_color.png`` and
``..._depth.png``, e.g. ``frame_20261123T140848.123Z_sim0000000012.005000000_color.png``.
Simulation time starts at 0 in every run, so the stamp alone repeats from one run to the
next; the wall clock keeps runs apart and sorts the files in the order they were saved. If a
name is taken all the same (one frame saved twice in a millisecond, two graphs writing to one
directory), ``_1``, ``_2``, ... is added to the stem: an existing file is never replaced.

Each file is encoded in memory, written to a hidden temporary file in the target directory
(with the mode of any new file: 0666 less the umask), flushed to disk and then hard-linked to
its final name, which fails instead of replacing a file; so a reader never sees a partial PNG.
On file systems without hard links (FAT, some network mounts) the names are first claimed by
creating them exclusively, and the temporary files renamed over those claims: there a reader
may see an empty file for a moment. Depth is stored as REP 118 16-bit millimetres: 0 where
there is no return (nan, inf, <= 0) or the value does not fit in 16 bits.
"""

from datetime import datetime, timezone
import errno
import os
import secrets
import time

import cv2
import numpy as np

_PNG_OPTIONS = [cv2.IMWRITE_PNG_COMPRESSION, 1]  # fast; PNG stays lossless at every level
_MAX_MM = np.iinfo(np.uint16).max
_MAX_SUFFIX = 1000  # names tried per frame before giving up
_KINDS = ('color', 'depth')


def depth_to_mm(depth: np.ndarray) -> np.ndarray:
    """Return metres as uint16 millimetres, 0 for no return or out of range."""
    with np.errstate(invalid='ignore'):
        mm = np.rint(depth.astype(np.float64) * 1000.0)
        valid = np.isfinite(mm) & (mm > 0) & (mm <= _MAX_MM)
    return np.where(valid, mm, 0).astype(np.uint16)


def frame_name(sec: int, nanosec: int, wall_time: float) -> str:
    """Return the file name stem of a frame stamped ``sec``.``nanosec``, saved at ``wall_time``.

    ``wall_time`` is in seconds since the epoch (``time.time()``); the name shows it in UTC.
    """
    saved = datetime.fromtimestamp(wall_time, timezone.utc)
    return (f'frame_{saved:%Y%m%dT%H%M%S}.{saved.microsecond // 1000:03d}Z_'
            f'sim{sec:010d}.{nanosec:09d}')


def save_frame(directory: str, sec: int, nanosec: int, rgb: np.ndarray,
               depth: np.ndarray | None, wall_time: float | None = None) -> list[str]:
    """Save an RGB frame and its depth (metres, optional) as PNGs; return the paths written.

    Creates ``directory`` if needed. ``wall_time`` (default: now) is the time of the save, for
    the name. On OSError nothing of this frame is left behind.
    """
    os.makedirs(directory, exist_ok=True)
    images = {'color': cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)}
    if depth is not None:
        images['depth'] = depth_to_mm(depth)
    stem = frame_name(sec, nanosec, time.time() if wall_time is None else wall_time)
    temporaries: list[str] = []
    try:
        for kind, image in images.items():
            temporaries.append(write_temporary(directory, f'{stem}_{kind}.png',
                                               encode_png(image)))
        for attempt in range(_MAX_SUFFIX):
            name = stem if attempt == 0 else f'{stem}_{attempt}'
            paths = [os.path.join(directory, f'{name}_{kind}.png') for kind in images]
            # A colour file alone must not take the stem of another frame's depth file.
            if any(os.path.lexists(os.path.join(directory, f'{name}_{kind}.png'))
                   for kind in _KINDS):
                continue
            try:
                publish_new(temporaries, paths)
            except FileExistsError:
                continue
            return paths
        raise FileExistsError(errno.EEXIST, f'{_MAX_SUFFIX} names for this frame are taken',
                              os.path.join(directory, stem))
    finally:
        for temporary in temporaries:
            remove(temporary)


def encode_png(image: np.ndarray) -> bytes:
    """Return ``image`` (BGR, grey or 16-bit) encoded as PNG."""
    ok, encoded = cv2.imencode('.png', image, _PNG_OPTIONS)
    if not ok:
        raise OSError(f'PNG encoding of a {image.dtype} {image.shape} image failed')
    return encoded.tobytes()


def write_temporary(directory: str, name: str, data: bytes) -> str:
    """Write ``data`` to a new hidden file in ``directory``, on disk; return its path."""
    temporary = os.path.join(directory, f'.{name}.{secrets.token_hex(6)}.tmp')
    # Not tempfile.mkstemp: its mode 0600 would stay with the saved file.
    fd = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o666)
    try:
        with os.fdopen(fd, 'wb') as file:
            file.write(data)
            file.flush()
            os.fsync(file.fileno())
    except BaseException:
        remove(temporary)
        raise
    return temporary


def publish_new(temporaries: list[str], paths: list[str]) -> None:
    """Give each temporary file its final name, in order, all or none.

    FileExistsError if a name is taken: a file is never replaced.
    """
    linked: list[str] = []
    try:
        for temporary, path in zip(temporaries, paths):
            os.link(temporary, path)
            linked.append(path)
    except OSError as error:
        _remove_all(linked)
        if isinstance(error, FileExistsError) or linked:
            raise
        _publish_by_rename(temporaries, paths)  # the file system has no hard links


def _publish_by_rename(temporaries: list[str], paths: list[str]) -> None:
    """:func:`publish_new` without hard links: claim every name, then rename onto the claims."""
    claimed: list[str] = []
    try:
        for path in paths:
            os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o666))
            claimed.append(path)
        for temporary, path in zip(temporaries, paths):
            os.replace(temporary, path)
    except BaseException:
        _remove_all(claimed)
        raise


def _remove_all(paths: list[str]) -> None:
    for path in paths:
        remove(path)


def remove(path: str) -> None:
    """Delete a file if it exists; cleanup after a failure must not hide that failure."""
    try:
        os.unlink(path)
    except OSError:
        pass
