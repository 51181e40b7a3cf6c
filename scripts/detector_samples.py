"""Make the README's pictures of the learned ball detector: detections on hard scenes, the curve.

Renders seeded scenes of the held-out hard set (:func:`ur_rg2_detector.scenes.hard_scenes`),
runs both detectors on each as the vision node does (find, then locate with the depth), and
draws what each reports as a ball: the learned detector's in green, the colour detector's in
magenta (a ball the depth confirms: a circle; a box the model saw that the depth refused:
a thin rectangle). Writes docs/detector_samples.png and copies the model's training curve to
docs/detector_training_curve.png.

usage: scripts/detector-samples [--model DIR] [--count N] [--seed S]
"""

import argparse
from pathlib import Path
import shutil

import cv2
import numpy as np
from ur_rg2_detector.scenes import hard_scenes
from ur_rg2_vision.detector import BallDetector
from ur_rg2_vision.learned import SHIPPED_MODEL, BallModel, LearnedBallDetector
from ur_rg2_vision.localize import locate_ball

ROOT = Path(__file__).resolve().parents[1]
LEARNED, COLOR = (0, 220, 0), (255, 0, 255)  # RGB
TILE = 400


def _draw(rgb: np.ndarray, detections, depth, k, colour, refused_too: bool) -> None:
    for detection in detections:
        centre = (round(detection.u), round(detection.v))
        if locate_ball(detection, depth, k) is not None:
            cv2.circle(rgb, centre, max(2, round(detection.radius)) + 2, colour, 2, cv2.LINE_AA)
        elif refused_too:
            r = round(detection.radius)
            cv2.rectangle(rgb, (centre[0] - r, centre[1] - r), (centre[0] + r, centre[1] + r),
                          colour, 1)


def main() -> None:
    """Render, detect, draw, write."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--model', default='', help='model directory (default: the shipped one)')
    parser.add_argument('--count', type=int, default=12)
    parser.add_argument('--seed', type=int, default=77)
    args = parser.parse_args()
    model = BallModel(args.model)
    learned, color = LearnedBallDetector(model, 4.0), BallDetector()
    tiles = []
    for shot in hard_scenes(args.count, args.seed):
        rgb = shot.rgb.copy()
        _draw(rgb, color.detect(shot.rgb, shot.k, shot.depth), shot.depth, shot.k, COLOR, False)
        _draw(rgb, learned.detect(shot.rgb, shot.k, shot.depth), shot.depth, shot.k, LEARNED, True)
        tile = cv2.resize(rgb, (TILE, TILE * 3 // 4), interpolation=cv2.INTER_AREA)
        label = shot.name.split(': ')[1]
        cv2.putText(tile, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3)
        cv2.putText(tile, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1)
        tiles.append(tile)
    columns = 4
    rows = [np.hstack(tiles[i:i + columns]) for i in range(0, len(tiles), columns)]
    grid = np.vstack(rows)
    out = ROOT / 'docs' / 'detector_samples.png'
    cv2.imwrite(str(out), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR))
    curve = Path(args.model or SHIPPED_MODEL) / 'training_curve.png'
    shutil.copyfile(curve, ROOT / 'docs' / 'detector_training_curve.png')
    print(out)


if __name__ == '__main__':
    main()
