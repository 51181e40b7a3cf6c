"""The labelled data set's files, without ROS: labels, the YOLO layout, progress.

A ball's label is the bounding box of the projected sphere
(:func:`ur_rg2_vision.sphere.sphere_box`). Layout (YOLO): ``images/{train,val}/NAME.png``,
``labels/{train,val}/NAME.txt`` with one line ``0 cx cy w h`` (normalised to the image size)
or nothing when the ball is out of view, ``depth/{train,val}/NAME.png`` (16-bit, millimetres,
0 = none) and ``data.yaml``. Names are six-digit sample numbers that continue from the largest
one present, and sample ``i`` goes to ``val`` when ``floor((i + 1) f) > floor(i f)`` for the
validation fraction ``f``: a run that appends continues the same split. Where each sample's
ball, camera and objects go: :mod:`ur_rg2_vision.placement`.
"""

from collections.abc import Sequence
import errno
import math
import os
from pathlib import Path
import re
import sys
import time
from typing import TextIO

import cv2
import numpy as np

from ur_rg2_vision.frame_store import encode_png, publish_new, remove, write_temporary
from ur_rg2_vision.sphere import sphere_box

SPLITS = ('train', 'val')
CLASS_ID = 0
CLASS_NAME = 'ball'
_NAME = re.compile(r'^(\d{6,})\.(png|txt)$')


# -- labels --------------------------------------------------------------------------------------

def yolo_label(box: tuple[float, float, float, float] | None, width: int, height: int
               ) -> tuple[float, float, float, float] | None:
    """Return a pixel box clipped to the image as normalised (cx, cy, w, h); None if outside.

    Pixel i covers [i - 0.5, i + 0.5] in the box's coordinates and [i, i + 1] in YOLO's.
    """
    if box is None:
        return None
    u0, v0, u1, v1 = box
    u0, u1 = max(u0 + 0.5, 0.0), min(u1 + 0.5, float(width))
    v0, v1 = max(v0 + 0.5, 0.0), min(v1 + 0.5, float(height))
    if u1 <= u0 or v1 <= v0:
        return None
    return ((u0 + u1) / 2 / width, (v0 + v1) / 2 / height, (u1 - u0) / width,
            (v1 - v0) / height)


def depth_png(depth: np.ndarray) -> bytes:
    """Return a depth image (m, inf: no return) as a 16-bit PNG in millimetres (0: none)."""
    millimetres = np.where(np.isfinite(depth), np.round(depth * 1000.0), 0.0)
    return encode_png(np.clip(millimetres, 0, 65535).astype(np.uint16))


def label_text(label: tuple[float, float, float, float] | None) -> str:
    """Return a label file's text: one YOLO line, or nothing when the ball is out of view."""
    if label is None:
        return ''
    return f'{CLASS_ID} ' + ' '.join(f'{v:.6f}' for v in label) + '\n'


def hidden_fraction(center: Sequence[float], radius: float, k: np.ndarray, depth: np.ndarray,
                    tolerance: float = 0.01) -> tuple[float, float]:
    """Return the fractions of the ball's inner pixels hidden by something nearer, and empty.

    Inner pixels are those whose ray meets the sphere shrunk to 90 % (the rendered ball is a
    mesh a little inside the true sphere); each should show the true sphere's depth within
    ``tolerance`` m. Nearer: the ball is hidden there (the arm, the pedestal). Farther: no ball
    there, so the frame does not show the ball where it is labelled. (0, 0) when no inner pixel
    is in the image.
    """
    box = sphere_box(center, radius, k)
    if box is None:
        return 0.0, 0.0
    height, width = depth.shape
    u0, v0 = max(int(math.floor(box[0])), 0), max(int(math.floor(box[1])), 0)
    u1, v1 = min(int(math.ceil(box[2])), width - 1), min(int(math.ceil(box[3])), height - 1)
    if u1 < u0 or v1 < v0:
        return 0.0, 0.0
    u, v = np.meshgrid(np.arange(u0, u1 + 1), np.arange(v0, v1 + 1))
    rays = np.stack([(u - k[0, 2]) / k[0, 0], (v - k[1, 2]) / k[1, 1], np.ones(u.shape)], -1)
    c = np.asarray(center, dtype=float)
    # |t d - c|^2 = s^2 with d = (x, y, 1): the nearer root t is the optical depth of the hit.
    a = np.einsum('...i,...i', rays, rays)
    b = rays @ c
    cc = c @ c
    inner = b * b - a * (cc - (0.9 * radius) ** 2) > 0
    if not inner.any():
        return 0.0, 0.0
    expected = (b - np.sqrt(np.maximum(b * b - a * (cc - radius * radius), 0.0))) / a
    seen = depth[v0:v1 + 1, u0:u1 + 1][inner]
    expected = expected[inner]
    with np.errstate(invalid='ignore'):
        nearer = np.count_nonzero(seen < expected - tolerance)
        farther = np.count_nonzero(~(seen <= expected + tolerance))  # nan and inf count too
    return nearer / seen.size, farther / seen.size


# -- files ---------------------------------------------------------------------------------------

def is_val(index: int, val_fraction: float) -> bool:
    """Return whether sample ``index`` belongs to the validation split."""
    return math.floor((index + 1) * val_fraction) > math.floor(index * val_fraction)


class DatasetWriter:
    """Writes samples into a YOLO data set directory; appends to what is there."""

    def __init__(self, root: str | os.PathLike, val_fraction: float,
                 renderer: str = '') -> None:
        self.root = Path(root).absolute()
        self.val_fraction = val_fraction
        self.renderer = renderer  # who drew the frames, recorded in data.yaml
        for kind in ('images', 'labels'):
            for split in SPLITS:
                (self.root / kind / split).mkdir(parents=True, exist_ok=True)
        self._check_data_yaml()
        self.removed_orphans = self._remove_orphan_labels()
        self.next_index = self._next_index()

    def _check_data_yaml(self) -> None:
        path = self.root / 'data.yaml'
        if path.exists():
            text = path.read_text()
            if not re.search(rf'^names:\s*\{{\s*{CLASS_ID}:\s*{CLASS_NAME}\s*\}}\s*$', text,
                             re.MULTILINE):
                raise ValueError(f'{path} exists and is not a data set of the class '
                                 f'{CLASS_ID}: {CLASS_NAME} alone; choose another --out')
        data = (f'path: {self.root}\ntrain: images/train\nval: images/val\n'
                f'names: {{{CLASS_ID}: {CLASS_NAME}}}\n')
        if self.renderer:
            data += f'renderer: {self.renderer!r}\n'
        temporary = write_temporary(str(self.root), 'data.yaml', data.encode())
        try:
            os.replace(temporary, path)
        finally:
            remove(temporary)

    def _names(self, kind: str, split: str) -> dict[int, Path]:
        names = {}
        for entry in (self.root / kind / split).iterdir():
            match = _NAME.match(entry.name)
            if match:
                names[int(match.group(1))] = entry
        return names

    def _remove_orphan_labels(self) -> int:
        """Delete labels whose image was never written (a run killed between the two)."""
        removed = 0
        for split in SPLITS:
            images = self._names('images', split)
            for index, label in self._names('labels', split).items():
                if index not in images:
                    remove(str(label))
                    removed += 1
        return removed

    def _next_index(self) -> int:
        indices = [i for kind in ('images', 'labels') for split in SPLITS
                   for i in self._names(kind, split)]
        return max(indices, default=-1) + 1

    def count(self) -> int:
        """Return how many samples (images) the data set holds."""
        return sum(len(self._names('images', split)) for split in SPLITS)

    def write(self, rgb: np.ndarray, label: tuple[float, float, float, float] | None,
              extras: dict[str, tuple[str, bytes]] | None = None) -> Path:
        """Write one sample under the next free name: the label (and extras) first, the image.

        All appear whole (written aside, then linked to a name no file has), so an image
        never exists without its label. ``extras``: more files of the sample, a folder beside
        ``images`` -> (file suffix, content), e.g. ``{'depth': ('.png', ...)}``. Returns the
        image's path.
        """
        extras = extras or {}
        while True:
            index = self.next_index
            self.next_index += 1
            split = 'val' if is_val(index, self.val_fraction) else 'train'
            name = f'{index:06d}'
            label_dir, image_dir = self.root / 'labels' / split, self.root / 'images' / split
            temporaries = [write_temporary(str(label_dir), f'{name}.txt',
                                           label_text(label).encode())]
            paths = [str(label_dir / f'{name}.txt')]
            try:
                for kind, (suffix, data) in extras.items():
                    folder = self.root / kind / split
                    folder.mkdir(parents=True, exist_ok=True)
                    temporaries.append(write_temporary(str(folder), name + suffix, data))
                    paths.append(str(folder / (name + suffix)))
                temporaries.append(write_temporary(
                    str(image_dir), f'{name}.png', encode_png(cv2.cvtColor(rgb,
                                                                           cv2.COLOR_RGB2BGR))))
                paths.append(str(image_dir / f'{name}.png'))
                try:
                    publish_new(temporaries, paths)
                except FileExistsError:
                    continue  # another writer took this name
                return Path(paths[-1])
            finally:
                for temporary in temporaries:
                    remove(temporary)


def check_writable(root: str | os.PathLike) -> None:
    """Raise OSError with the reason if a data set cannot be written under ``root``.

    Creates nothing: a file is written and deleted in ``root`` or its nearest existing parent.
    """
    path = Path(root).absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    if not path.is_dir():
        raise NotADirectoryError(errno.ENOTDIR, 'not a directory', str(path))
    remove(write_temporary(str(path), 'probe', b''))


# -- progress ------------------------------------------------------------------------------------

def format_duration(seconds: float) -> str:
    """Return ``H:MM:SS`` (or ``--:--`` when unknown)."""
    if not math.isfinite(seconds) or seconds < 0:
        return '--:--'
    seconds = int(round(seconds))
    return f'{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}'


class Progress:
    """A progress bar with rate and ETA on a terminal; a plain line every ``every`` otherwise."""

    def __init__(self, total: int, stream: TextIO = sys.stderr, every: int = 10,
                 tty: bool | None = None, clock=time.monotonic) -> None:
        self.total = total
        self.done = 0
        self.stream = stream
        self.every = max(every, 1)
        self.tty = stream.isatty() if tty is None else tty
        self._clock = clock
        self._start = clock()

    def line(self) -> str:
        """Return the current state as one line."""
        elapsed = self._clock() - self._start
        rate = self.done / elapsed if elapsed > 0 else 0.0
        eta = (self.total - self.done) / rate if rate > 0 else float('inf')
        share = self.done / self.total if self.total else 1.0
        text = (f'{self.done}/{self.total} {share:4.0%} {rate:.2f} samples/s '
                f'ETA {format_duration(eta)}')
        if self.tty:
            filled = int(round(share * 30))
            text = '[' + '#' * filled + '-' * (30 - filled) + '] ' + text
        return text

    def advance(self) -> None:
        """Count one sample written and show it."""
        self.done += 1
        if self.tty:
            self.stream.write('\r' + self.line())
            if self.done == self.total:
                self.stream.write('\n')
        elif self.done % self.every == 0 or self.done == self.total:
            self.stream.write(self.line() + '\n')
        self.stream.flush()

    def close(self) -> None:
        """End the bar's line on a terminal (after an interruption)."""
        if self.tty and 0 < self.done < self.total:
            self.stream.write('\n')
            self.stream.flush()
