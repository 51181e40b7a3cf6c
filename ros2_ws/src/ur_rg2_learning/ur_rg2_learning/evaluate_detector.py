"""``evaluate_detector``: recall, precision and mAP50 of a ball detector on a ``dataset`` split.

Runs the exported ONNX model as the ``vision`` node does (ONNX Runtime, no torch), or
with ``--detector color`` the colour detector, on the validation images of a data set (its
``data.yaml``; ``--split train`` for the others). A detection is right when its box overlaps
a labelled ball's box by IoU >= 0.5; every image holds at most one ball.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
import sys

import cv2
import numpy as np
from ur_rg2_vision.detector import BallDetector
from ur_rg2_vision.learned import BallModel, ModelError
import yaml

IOU = 0.5


@dataclass
class Scores:
    """Counts over a set of images, and the ranked detections for the average precision."""

    images: int = 0
    balls: int = 0
    found: int = 0  # balls matched by a detection
    false: int = 0  # detections that match no ball
    ranked: list[tuple[float, bool]] | None = None  # (score, right) of every detection

    @property
    def recall(self) -> float:
        """Return the share of the balls found."""
        return self.found / self.balls if self.balls else 1.0

    @property
    def precision(self) -> float:
        """Return the share of the detections that are balls."""
        detections = self.found + self.false
        return self.found / detections if detections else 1.0

    @property
    def map50(self) -> float:
        """Average precision at IoU 0.5 (all-point interpolation, as the VOC/COCO tools)."""
        if not self.balls:
            return 1.0
        ranked = sorted(self.ranked or [], key=lambda item: -item[0])
        right = np.cumsum([hit for _, hit in ranked])
        recall = np.concatenate([[0.0], right / self.balls, [right[-1] / self.balls if
                                                             len(right) else 0.0]])
        precision = np.concatenate([[1.0], right / np.arange(1, len(ranked) + 1), [0.0]])
        precision = np.maximum.accumulate(precision[::-1])[::-1]
        return float(np.sum(np.diff(recall) * precision[1:]))

    def line(self) -> str:
        """Return the result line evaluate_detector prints."""
        return (f'recall {self.recall:.3f} precision {self.precision:.3f} mAP50 '
                f'{self.map50:.3f} over {self.images} images')


def iou(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    """Return the intersection over union of two boxes (u0, v0, u1, v1)."""
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    if w <= 0 or h <= 0:
        return 0.0
    inter = w * h
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


def split_images(data: str | Path, split: str = 'val') -> list[tuple[Path, Path]]:
    """Return (image, label) paths of a data set's split (data.yaml: a folder or a list)."""
    root = Path(data)
    config = yaml.safe_load((root / 'data.yaml').read_text())
    base = Path(config.get('path') or root)
    if not base.is_absolute():
        base = root / base
    folders = config[split]
    pairs = []
    for folder in [folders] if isinstance(folders, str) else folders:
        images = base / folder
        labels = Path(str(images).replace('/images/', '/labels/'))
        for image in sorted(images.glob('*.png')):
            pairs.append((image, labels / (image.stem + '.txt')))
    return pairs


def label_box(path: Path, width: int, height: int) -> tuple[float, ...] | None:
    """Return the labelled ball's box in pixels, None for an empty label."""
    words = path.read_text().split()
    if not words:
        return None
    cx, cy, w, h = (float(x) for x in words[1:5])
    return ((cx - w / 2) * width, (cy - h / 2) * height, (cx + w / 2) * width,
            (cy + h / 2) * height)


def color_boxes(detector: BallDetector, rgb: np.ndarray) -> list[tuple[float, ...]]:
    """Return the colour detector's balls as boxes with their coverage as the score."""
    return [(d.u - d.radius, d.v - d.radius, d.u + d.radius, d.v + d.radius, d.coverage)
            for d in detector.detect(rgb)]


def evaluate(boxes, pairs: list[tuple[Path, Path]]) -> Scores:
    """Score ``boxes(rgb) -> [(u0, v0, u1, v1, score)]`` on (image, label) pairs."""
    scores = Scores(ranked=[])
    for image_path, label_path in pairs:
        rgb = cv2.cvtColor(cv2.imread(str(image_path)), cv2.COLOR_BGR2RGB)
        truth = label_box(label_path, rgb.shape[1], rgb.shape[0])
        scores.images += 1
        scores.balls += truth is not None
        matched = False
        for box in sorted(boxes(rgb), key=lambda b: -b[4]):
            right = truth is not None and not matched and iou(box, truth) >= IOU
            matched |= right
            scores.found += right
            scores.false += not right
            scores.ranked.append((box[4], right))
    return scores


def main(argv: list[str] | None = None) -> int:
    """Print ``recall R precision P mAP50 M over N images``; exit 0, 2 on bad input."""
    parser = argparse.ArgumentParser(prog='evaluate_detector', description=__doc__.split('\n')[0])
    parser.add_argument('--model', default='', metavar='DIR',
                        help='model directory (train_detector --out); default: the model '
                        'shipped with ur_rg2_vision')
    parser.add_argument('--data', required=True, metavar='DIR',
                        help='data set directory (dataset --out), with its data.yaml')
    parser.add_argument('--split', default='val', choices=['val', 'train'])
    parser.add_argument('--detector', default='learned', choices=['learned', 'color'],
                        help="the learned model, or the colour detector (the vision node's "
                        'default, red balls) for comparison')
    args = parser.parse_args(argv)
    try:
        pairs = split_images(args.data, args.split)
    except (OSError, KeyError, TypeError, yaml.YAMLError) as error:
        print(f'evaluate_detector: cannot read the data set {args.data}: {error}',
              file=sys.stderr)
        return 2
    if not pairs:
        print(f'evaluate_detector: no {args.split} images in {args.data}', file=sys.stderr)
        return 2
    if args.detector == 'color':
        detector = BallDetector()
        boxes = lambda rgb: color_boxes(detector, rgb)  # noqa: E731
    else:
        try:
            boxes = BallModel(args.model).boxes
        except ModelError as error:
            print(f'evaluate_detector: {error}', file=sys.stderr)
            return 2
    print(evaluate(boxes, pairs).line())
    return 0


if __name__ == '__main__':
    sys.exit(main())
