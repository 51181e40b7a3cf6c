"""Benchmark of the two ball detectors side by side, on a held-out hard set, and the shipped model.

1. Hard set: seeded frames rendered by the sim's world and camera
   (:func:`ur_rg2_vision.scenes.hard_scenes`): random camera poses, floor colours and lights,
   cubes, boxes and flat discs of any colour (the ball's too), and in most frames one ball of
   any colour and 1.5-8 cm radius. Each detector does the vision node's per-frame work (find,
   then confirm and locate with the depth) with OpenCV on one thread: balls found (of those
   at least 40% visible), false balls (a position where there is no ball, or more than a
   radius off it), 3D error, time per frame (with the load average before and after: the
   machine is shared).
2. The shipped model: its training time and size (from its detector.json), its validation
   numbers as train_detector measured them.
3. Pipeline with ``detector:=learned``: colour stamp -> ``ball/position`` in another process,
   as the vision benchmark measures it for the colour detector.

Run alone with ``python -m bench.detector_bench``.
"""

import json
import os

import cv2
import numpy as np

from bench.processes import percentile
from bench.vision_bench import _pipeline, _render_frames

HARD_FRAMES = 200
SEED = 4242  # apart from the tests' and the data sets' seeds
MIN_VISIBLE = 0.4


def _hard_set() -> dict[str, dict]:
    from ur_rg2_vision.detector import BallDetector
    from ur_rg2_vision.learned import BallModel, LearnedBallDetector
    from ur_rg2_vision.localize import locate_first
    from ur_rg2_vision.scenes import hard_scenes

    detectors = {'color': BallDetector(),
                 'learned': LearnedBallDetector(BallModel(), 4.0)}
    results = {name: {'balls': 0, 'found': 0, 'false': 0, 'errors': [], 'times': [],
                      'empty': 0} for name in detectors}
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        for shot in hard_scenes(HARD_FRAMES, SEED):
            counted = shot.centre is not None and shot.visible >= MIN_VISIBLE
            for name, detector in detectors.items():
                result = results[name]
                start = cv2.getTickCount()
                position = locate_first(detector.detect(shot.rgb, shot.k), shot.depth, shot.k)
                result['times'].append(1000 * (cv2.getTickCount() - start)
                                       / cv2.getTickFrequency())
                result['balls'] += counted
                result['empty'] += shot.centre is None
                if position is None:
                    continue
                centre = np.array([position.x, position.y, position.z])
                if shot.centre is None or np.linalg.norm(centre - shot.centre) > shot.radius:
                    result['false'] += 1
                elif counted:
                    result['found'] += 1
                    result['errors'].append(1000 * np.linalg.norm(centre - shot.centre))
    finally:
        cv2.setNumThreads(threads)
    return results


def run() -> list[tuple[str, str, str]]:
    """Measure both detectors; return benchmark rows (metric, measured, target)."""
    from ur_rg2_vision.learned import MODEL_FILE, SETTINGS_FILE, SHIPPED_MODEL

    load_before = os.getloadavg()[0]
    results = _hard_set()
    load_hard = os.getloadavg()[0]
    settings = json.loads((SHIPPED_MODEL / SETTINGS_FILE).read_text())
    training, validation = settings['training'], settings['validation']
    size = os.path.getsize(SHIPPED_MODEL / MODEL_FILE) / 1e6
    _, default = _render_frames()
    pipeline = _pipeline(default, {'detector': 'learned'})
    load_pipeline = os.getloadavg()[0]
    rows = []
    hard = f'hard set ({HARD_FRAMES} frames, seed {SEED})'
    for name, target_recall, target_error, target_time in (
            ('color', '', '', ''), ('learned', '>= 95%', 'median <= 5 mm', 'p95 <= 30 ms')):
        r = results[name]
        rows += [
            (f'detector {name}: {hard}, balls found',
             f'{r["found"]} of {r["balls"]} ({100 * r["found"] / r["balls"]:.1f}%)',
             target_recall),
            (f'detector {name}: {hard}, false balls',
             f'{r["false"]} (in {HARD_FRAMES} frames, {r["empty"]} without a ball)',
             '0' if name == 'learned' else ''),
            (f'detector {name}: {hard}, 3D error, mm median / p95',
             f'{percentile(r["errors"], 50):.2f} / {percentile(r["errors"], 95):.2f}',
             target_error),
            (f'detector {name}: detection + 3D per 640x480 frame, one thread, ms p50 / p95',
             f'{percentile(r["times"], 50):.1f} / {percentile(r["times"], 95):.1f} (load '
             f'{load_before:.1f}-{load_hard:.1f})', target_time),
        ]
    rows += [
        ('detector learned: colour stamp -> ball/position in another process, ms p50 / p95',
         f'{pipeline["p50"]:.1f} / {pipeline["p95"]:.1f} (load {load_pipeline:.1f})',
         'p95 <= 33 ms'),
        ('detector learned: frames processed, fed at 30 Hz (ball/position)',
         f'{pipeline["positions"]} of {pipeline["sent"]} (load {load_pipeline:.1f})', 'all'),
        ('detector learned: shipped model, training time (train_detector, this machine)',
         f'{training["seconds"] / 60:.1f} min ({training["epochs"]} epochs, imgsz '
         f'{training["imgsz"]})', '<= 60 min'),
        ('detector learned: shipped model, size (model.onnx)', f'{size:.1f} MB', 'a few MB'),
        ('detector learned: shipped model, its validation split (evaluate_detector)',
         f'recall {validation["recall"]:.3f} precision {validation["precision"]:.3f} '
         f'mAP50 {validation["mAP50"]:.3f} over {validation["images"]} images', ''),
    ]
    return rows


if __name__ == '__main__':
    from bench.__main__ import print_table

    print_table(run())
