"""Make the picture of a labelled data set in docs/reference.md: samples with their boxes drawn.

Reads a data set written by ``dataset`` (images/, labels/), takes the first COUNT samples in
name order (with the first one whose label is empty among them, if any), draws each YOLO box
in green with an enlarged view of it in the corner (a sample whose label is empty says so) and
writes one PNG grid.

usage: scripts/dataset-samples DATASET_DIR [OUTPUT.png] [--count N] [--columns N] [--width PX]
       (default output docs/dataset_samples.png)
"""

import argparse
from pathlib import Path
import sys

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
GREEN = (0, 200, 0)  # BGR
INSET = 120  # px, width of the enlarged view of the box


def labelled_tile(image_path: Path, label_path: Path, width: int) -> np.ndarray:
    """Return an image scaled to ``width`` with its label's box drawn."""
    image = cv2.imread(str(image_path))
    height, full_width = image.shape[:2]
    lines = label_path.read_text().split('\n') if label_path.exists() else []
    for line in filter(None, lines):
        _, cx, cy, w, h = (float(v) for v in line.split())
        x0, y0 = round((cx - w / 2) * full_width), round((cy - h / 2) * height)
        x1, y1 = round((cx + w / 2) * full_width), round((cy + h / 2) * height)
        # The view of the ball before the box covers it: twice the box, at least 40 px.
        half = max(x1 - x0, y1 - y0, 20)
        mx, my = (x0 + x1) // 2, (y0 + y1) // 2
        crop = image[max(my - half, 0):my + half, max(mx - half, 0):mx + half].copy()
        cv2.rectangle(crop, (x0 - max(mx - half, 0), y0 - max(my - half, 0)),
                      (x1 - 1 - max(mx - half, 0), y1 - 1 - max(my - half, 0)), GREEN, 1)
        cv2.rectangle(image, (x0 - 2, y0 - 2), (x1 + 1, y1 + 1), GREEN, 2)
    scale = width / full_width
    tile = cv2.resize(image, (width, round(height * scale)), interpolation=cv2.INTER_AREA)
    if any(lines):
        inset = cv2.resize(crop, (INSET, INSET * crop.shape[0] // crop.shape[1]),
                           interpolation=cv2.INTER_NEAREST)
        ih, iw = inset.shape[:2]
        tile[-ih - 6:-6, -iw - 6:-6] = inset
        cv2.rectangle(tile, (width - iw - 7, tile.shape[0] - ih - 7),
                      (width - 6, tile.shape[0] - 6), (255, 255, 255), 1)
    text = f'{image_path.parent.name}/{image_path.stem}' + ('' if any(lines) else ' (empty)')
    cv2.putText(tile, text, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(tile, text, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1,
                cv2.LINE_AA)
    return tile


def main() -> int:
    """Write the grid; return the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('dataset', type=Path, help='a data set written by dataset')
    parser.add_argument('output', type=Path, nargs='?',
                        default=ROOT / 'docs' / 'dataset_samples.png')
    parser.add_argument('--count', type=int, default=6, help='samples in the grid')
    parser.add_argument('--columns', type=int, default=3)
    parser.add_argument('--width', type=int, default=320, help='width of one tile, pixels')
    args = parser.parse_args()
    every = sorted(args.dataset.glob('images/*/*.png'), key=lambda p: p.stem)

    def empty(image: Path) -> bool:
        label = args.dataset / 'labels' / image.parent.name / f'{image.stem}.txt'
        return not label.read_text().strip()
    images = every[:args.count]
    if not any(map(empty, images)):
        images = every[:args.count - 1] + [p for p in every if empty(p)][:1]
    if not images:
        print(f'no images under {args.dataset}/images', file=sys.stderr)
        return 1
    tiles = [labelled_tile(p, args.dataset / 'labels' / p.parent.name / f'{p.stem}.txt',
                           args.width) for p in images]
    blank = np.full_like(tiles[0], 255)
    tiles += [blank] * (-len(tiles) % args.columns)
    rows = [np.hstack(tiles[i:i + args.columns]) for i in range(0, len(tiles), args.columns)]
    if not cv2.imwrite(str(args.output), np.vstack(rows)):
        print(f'cannot write {args.output}', file=sys.stderr)
        return 1
    print(args.output)
    return 0


if __name__ == '__main__':
    sys.exit(main())
