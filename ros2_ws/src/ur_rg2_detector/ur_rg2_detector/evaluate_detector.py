"""``evaluate_detector``: recall, precision and mAP50 of a ball detector on a ``dataset`` split.

Runs the exported ONNX model as the ``vision`` node does (ONNX Runtime, no torch), or
with ``--detector color`` the colour detector, on the validation images of a data set (its
``data.yaml``; ``--split train`` for the others). First the network alone: a box over the
model's threshold is right when it overlaps a labelled ball's box by IoU >= 0.5; every image
holds at most one ball. A ball less than 40 % visible (cut by the border or behind a box, from
the sample's meta) is a difficult one, as PASCAL VOC's: neither a miss when no box finds it nor
a false box when one does; a second line counts every labelled ball. A model that sees the
depth too (``detector.json``'s ``inputs``) is fed the ``depth/`` image beside each one. Then
the node's whole pipeline (the detector's candidates, the first that the depth confirms as a
sphere gives the 3D centre): right when that centre is within the ball's radius of the true
one. Each overall and per colour group
(saturated, pastel, white, grey, dark, patterned); the pipeline and the groups need the depth
and meta files that ``scripts/detector-data`` (:mod:`ur_rg2_detector.scene_dataset`) writes
beside the images.
``--thresholds T1,T2,...`` instead prints both overall at each of these score thresholds: to
choose the node's threshold on a validation split, not on the held-out one.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
import json
from pathlib import Path
import sys

import cv2
import numpy as np
from ur_rg2_vision.detector import DEFAULT_MIN_RADIUS_PX, BallDetector
from ur_rg2_vision.learned import BallModel, LearnedBallDetector, ModelError
import yaml

from ur_rg2_detector.scenes import MIN_VISIBLE

IOU = 0.5
GROUPS = ('saturated', 'pastel', 'white', 'grey', 'dark', 'patterned')


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


def color_boxes(detector: BallDetector, rgb: np.ndarray, _depth: np.ndarray | None = None
                ) -> list[tuple[float, ...]]:
    """Return the colour detector's balls as boxes with their coverage as the score."""
    return [(d.u - d.radius, d.v - d.radius, d.u + d.radius, d.v + d.radius, d.coverage)
            for d in detector.detect(rgb)]


def evaluate(boxes, pairs: list[tuple[Path, Path]], groups: dict[str, Scores] | None = None,
             every_label: Scores | None = None) -> Scores:
    """Score ``boxes(rgb, depth) -> [(u0, v0, u1, v1, score)]`` on (image, label) pairs.

    ``depth``: the sample's depth image (metres), None when it has none. A ball less than
    :data:`MIN_VISIBLE` visible (the sample's meta) is difficult: the box that finds it is
    neither right nor false, and no box missing it. ``groups``: also score each image in its
    colour group's entry (from the sample's meta), added when missing. ``every_label``: also
    score it there with every labelled ball counted.
    """
    scores = Scores(ranked=[])
    for image_path, label_path in pairs:
        rgb = cv2.cvtColor(cv2.imread(str(image_path)), cv2.COLOR_BGR2RGB)
        truth = label_box(label_path, rgb.shape[1], rgb.shape[0])
        meta = sample_meta(image_path)
        difficult = truth is not None and meta is not None and meta['visible'] < MIN_VISIBLE
        counts = [(scores, difficult)]
        if groups is not None and meta is not None:
            counts.append((groups.setdefault(meta['group'], Scores(ranked=[])), difficult))
        if every_label is not None:
            counts.append((every_label, False))
        found = sorted(boxes(rgb, read_depth(image_path)), key=lambda b: -b[4])
        for count, ignored in counts:
            count.images += 1
            count.balls += truth is not None and not ignored
            matched = False
            for box in found:
                right = truth is not None and not matched and iou(box, truth) >= IOU
                matched |= right
                if right and ignored:
                    continue
                count.found += right
                count.false += not right
                count.ranked.append((box[4], right))
    return scores


def sample_path(image: Path, kind: str, suffix: str) -> Path:
    """Return the path of a sample's other file (``depth``, ``meta``: scene_dataset's)."""
    return Path(str(image.with_suffix(suffix)).replace('/images/', f'/{kind}/'))


def read_depth(image: Path) -> np.ndarray | None:
    """Return a sample's depth image in metres (inf: no return), None when it has none."""
    path = sample_path(image, 'depth', '.png')
    millimetres = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if path.is_file() else None
    if millimetres is None:
        return None
    depth = millimetres.astype(np.float32) / 1000.0
    depth[millimetres == 0] = np.inf
    return depth


def sample_meta(image: Path) -> dict | None:
    """Return a sample's meta (colour group, camera matrix, ball), None when it has none."""
    path = sample_path(image, 'meta', '.json')
    return json.loads(path.read_text()) if path.is_file() else None


@dataclass
class Located(Scores):
    """The node's pipeline: balls located in 3D (right: within the ball's radius of it)."""

    errors: list[float] = field(default_factory=list)  # m, of the balls found

    def line(self) -> str:
        """Return the result line, with the median 3D error."""
        error = f'{1000 * float(np.median(self.errors)):.1f} mm' if self.errors else '-'
        return f'{super().line()}, {self.false} false balls, 3D error median {error}'


def evaluate_pipeline(detector, pairs: list[tuple[Path, Path]],
                      groups: dict[str, Located]) -> Located:
    """Score the vision node's pipeline (detect, then locate with the depth) per colour group.

    Needs scene_dataset's depth and meta beside each image; a ball counts when at least
    :data:`MIN_VISIBLE` of it is seen (a sliver at the border or behind a box is no target).
    """
    from ur_rg2_vision.localize import locate_ball
    total = Located(ranked=[])
    for image_path, _ in pairs:
        meta, depth = sample_meta(image_path), read_depth(image_path)
        if meta is None or depth is None:
            continue
        rgb = cv2.cvtColor(cv2.imread(str(image_path)), cv2.COLOR_BGR2RGB)
        k = np.asarray(meta['k'], dtype=float)
        centre = None if meta['centre'] is None else np.asarray(meta['centre'])
        counted = centre is not None and meta['visible'] >= MIN_VISIBLE
        position, score = None, 0.0
        for detection in detector.detect(rgb, k, depth):
            position = locate_ball(detection, depth, k)
            if position is not None:
                score = detection.coverage
                break
        group = groups.setdefault(meta['group'], Located(ranked=[]))
        for count in (total, group):
            count.images += 1
            count.balls += counted
            if position is None:
                continue
            located = np.array([position.x, position.y, position.z])
            right = centre is not None and np.linalg.norm(located - centre) <= meta['radius']
            if right and counted:
                count.found += 1
                count.errors.append(float(np.linalg.norm(located - centre)))
            count.false += not right
            count.ranked.append((score, bool(right and counted)))
    return total


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
    parser.add_argument('--min-radius-px', type=float, default=DEFAULT_MIN_RADIUS_PX,
                        help="the vision node's min_radius_px")
    parser.add_argument('--thresholds', default='', metavar='T1,T2,...',
                        help="the learned model at each of these score thresholds instead of "
                        "its own: one line per threshold, the network alone and the node's "
                        'pipeline overall')
    args = parser.parse_args(argv)
    try:
        thresholds = [float(t) for t in args.thresholds.split(',') if t.strip()]
    except ValueError:
        parser.error('--thresholds takes numbers between 0 and 1, comma-separated')
    if not all(0 < t < 1 for t in thresholds) or (thresholds and args.detector != 'learned'):
        parser.error('--thresholds takes numbers between 0 and 1, for the learned detector')
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
        boxes = lambda rgb, depth: color_boxes(detector, rgb)  # noqa: E731
    else:
        try:
            model = BallModel(args.model)
        except ModelError as error:
            print(f'evaluate_detector: {error}', file=sys.stderr)
            return 2
        if model.needs_depth and read_depth(pairs[0][0]) is None:
            print(f'evaluate_detector: the model sees the depth too, and {args.data} has no '
                  'depth/ images beside its images (scripts/detector-data writes them)',
                  file=sys.stderr)
            return 2
        boxes = model.boxes
        detector = LearnedBallDetector(model, args.min_radius_px)
    if thresholds:
        print(f'threshold: network alone | node pipeline ({args.split} split)')
        for threshold in thresholds:
            model.confidence = threshold
            print(f'  {threshold:g}: {evaluate(boxes, pairs).line()} | '
                  f'{evaluate_pipeline(detector, pairs, {}).line()}', flush=True)
        return 0
    groups: dict[str, Scores] = {}
    every_label = Scores(ranked=[])
    alone = evaluate(boxes, pairs, groups, every_label)
    print(f'network alone ({args.detector}, at its threshold; balls at least {MIN_VISIBLE:.0%} '
          'visible, a box on a less visible one neither right nor false):')
    print(f'  all: {alone.line()}')
    for name in sorted(groups, key=lambda g: GROUPS.index(g) if g in GROUPS else len(GROUPS)):
        print(f'  {name}: {groups[name].line()}')
    print(f'  every labelled ball: {every_label.line()}')
    located: dict[str, Located] = {}
    total = evaluate_pipeline(detector, pairs, located)
    if not total.images:
        print('pipeline: no depth/ and meta/ beside the images (scene_dataset writes them)')
        return 0
    print(f'node pipeline (detect, then the depth confirms and locates; right within the '
          f"ball's radius; balls at least {MIN_VISIBLE:.0%} visible):")
    print(f'  all: {total.line()}')
    for name in sorted(located, key=lambda g: GROUPS.index(g) if g in GROUPS else len(GROUPS)):
        print(f'  {name}: {located[name].line()}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
