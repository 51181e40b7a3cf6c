"""The detector's training frames: loaded, filtered by contrast, cropped and augmented.

Frames are scaled to the input size and held in memory; each training step takes random crops
of them (the network is fully convolutional), flipped, with their colour channels shuffled and
their brightness and contrast changed; some crops are centred on the network's own false peaks
(:func:`hard_negatives`, hard negative mining). No ROS; torch only where the network runs.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from ur_rg2_vision.learned_input import depth_relief

from ur_rg2_detector.evaluate_detector import label_box, read_depth

HARD_SCORE = 0.1  # a peak from this score on outside the frame's ball is a hard negative


def ball_contrast(bgr: np.ndarray, box: tuple[float, float, float, float]) -> float:
    """Return how far a ball stands out: |median value of its core - of a ring around it|.

    Value is the brightest channel (0-1); the core is within 0.6 of the box's radius of its
    centre, the ring 1.3-2.0 radii (plus a pixel or three) out; 1.0 when either is empty.
    """
    cx, cy = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
    radius = max(box[2] - box[0], box[3] - box[1]) / 2
    value = bgr.max(axis=2) / 255.0
    ys, xs = np.mgrid[0:bgr.shape[0], 0:bgr.shape[1]]
    distance = np.hypot(xs - cx, ys - cy)
    core = value[distance <= 0.6 * radius]
    ring = value[(distance >= 1.3 * radius + 1) & (distance <= 2.0 * radius + 3)]
    if not core.size or not ring.size:
        return 1.0
    return float(abs(np.median(core) - np.median(ring)))


def plain_pairs(pairs: list[tuple[Path, Path]], min_contrast: float
                ) -> list[tuple[Path, Path]]:
    """Return the samples without a ball or whose ball's contrast is at least ``min_contrast``."""
    kept = []
    for image, label in pairs:
        bgr = cv2.imread(str(image))
        if bgr is None:
            raise OSError(f'cannot read {image}')
        box = label_box(label, bgr.shape[1], bgr.shape[0])
        if box is None or ball_contrast(bgr, box) >= min_contrast:
            kept.append((image, label))
    return kept


def load_split(pairs: list[tuple[Path, Path]], size: tuple[int, int], depth: bool = False
               ) -> tuple[np.ndarray, np.ndarray | None,
                          list[tuple[float, float, float, float] | None]]:
    """Return a split's frames scaled to ``size`` (height, width): uint8 RGB, reliefs, boxes.

    Reliefs (float16, :func:`depth_relief`) with ``depth``, else None; OSError when a frame
    or its depth image cannot be read.
    """
    height, width = size
    images = np.empty((len(pairs), height, width, 3), np.uint8)
    reliefs = np.empty((len(pairs), height, width), np.float16) if depth else None
    boxes = []
    for i, (image, label) in enumerate(pairs):
        bgr = cv2.imread(str(image))
        if bgr is None:
            raise OSError(f'cannot read {image}')
        images[i] = cv2.resize(bgr, (width, height), interpolation=cv2.INTER_AREA)[..., ::-1]
        if reliefs is not None:
            metres = read_depth(image)
            if metres is None:
                raise OSError(f'no depth image for {image} (scripts/detector-data writes them)')
            reliefs[i] = depth_relief(metres, size)
        boxes.append(label_box(label, width, height))
    return images, reliefs, boxes


def network_input(rgb: np.ndarray, relief: np.ndarray | None) -> np.ndarray:
    """Return a frame (RGB 0-255) as the network takes it: float32 RGB 0-1 [and the relief]."""
    channels = [rgb.astype(np.float32) / 255.0]
    if relief is not None:
        channels.append(relief[..., None].astype(np.float32))
    return np.concatenate(channels, axis=2)


def augment(rng: np.random.Generator, image: np.ndarray,
            box: tuple[float, float, float, float] | None, crop: tuple[int, int],
            relief: np.ndarray | None = None, hard: np.ndarray | None = None,
            hard_share: float = 0.0
            ) -> tuple[np.ndarray, tuple[float, float, float, float] | None]:
    """Return a random crop of a frame (often about its ball) with its clipped box.

    The crop as the network takes it (:func:`network_input`), with ``relief`` when given.
    ``hard``: the frame's hard negatives (x, y rows, input pixels); ``hard_share`` of the
    crops are centred on one of them.
    """
    height, width = image.shape[:2]
    ch, cw = crop
    centre = None
    if hard is not None and len(hard) and rng.uniform() < hard_share:
        centre = hard[rng.integers(len(hard))]
    elif box is not None and rng.uniform() < 0.7:
        centre = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
    if centre is not None:
        cx, cy = centre
        x0 = int(np.clip(cx - rng.uniform(0.1, 0.9) * cw, 0, width - cw))
        y0 = int(np.clip(cy - rng.uniform(0.1, 0.9) * ch, 0, height - ch))
    else:
        x0, y0 = int(rng.integers(0, width - cw + 1)), int(rng.integers(0, height - ch + 1))
    patch = image[y0:y0 + ch, x0:x0 + cw]
    relief = None if relief is None else relief[y0:y0 + ch, x0:x0 + cw]
    if box is not None:
        u0, v0 = max(box[0] - x0, 0.0), max(box[1] - y0, 0.0)
        u1, v1 = min(box[2] - x0, float(cw)), min(box[3] - y0, float(ch))
        # A ball whose centre the crop cuts off is no ball of this crop.
        centre_in = 0 <= (box[0] + box[2]) / 2 - x0 < cw and 0 <= (box[1] + box[3]) / 2 - y0 < ch
        box = (u0, v0, u1, v1) if centre_in and u1 > u0 and v1 > v0 else None
    if rng.uniform() < 0.5:
        patch = patch[:, ::-1]
        relief = None if relief is None else relief[:, ::-1]
        if box is not None:
            box = (cw - box[2], box[1], cw - box[0], box[3])
    patch = patch[..., rng.permutation(3)].astype(np.float32)
    patch = patch * rng.uniform(0.7, 1.3) + rng.uniform(-30, 30)
    return network_input(np.clip(patch, 0, 255, out=patch), relief), box


def hard_negatives(torch, net, images: np.ndarray, reliefs: np.ndarray | None,
                   boxes: list[tuple[float, float, float, float] | None]) -> list[np.ndarray]:
    """Return each frame's false peaks: (x, y) rows, input pixels, of the network's peaks.

    A peak (score at least ``HARD_SCORE``) whose centre is outside the frame's ball box.
    """
    from ur_rg2_detector.detector_net import Exported

    decoded = Exported(net).eval()
    found = []
    with torch.no_grad():
        for start in range(0, len(images), 32):
            chunk = range(start, min(start + 32, len(images)))
            x = torch.from_numpy(np.stack([network_input(
                images[i], None if reliefs is None else reliefs[i]) for i in chunk]))
            for i, rows in zip(chunk, decoded(x.permute(0, 3, 1, 2)).numpy()):
                cx, cy, score = rows[0], rows[1], rows[4]
                peak = score >= HARD_SCORE
                box = boxes[i]
                if box is not None:
                    peak &= (cx < box[0]) | (cx > box[2]) | (cy < box[1]) | (cy > box[3])
                found.append(np.stack([cx[peak], cy[peak]], axis=1))
    net.train()
    return found
