"""Benchmark of the two ball detectors side by side, on held-out hard sets, and the shipped model.

1. Hard sets: seeded frames rendered by the sim's world and camera
   (:func:`ur_rg2_detector.scenes.hard_scenes`, seeds the training never used): random camera
   poses, floor colours and lights, cubes, boxes and flat discs of any colour (the ball's
   too), and in most frames one ball of 1.5-8 cm radius: of a saturated colour (both
   detectors), then of a plain one (pastel, white, grey, dark; the learned detector). Each
   detector does the vision node's per-frame work (find, then confirm and locate with the
   depth) with OpenCV on one thread: balls found (of those at least 40% visible), false balls
   (a position where there is no ball, or more than a radius off it), 3D error, time per
   frame (with the load average before and after: the machine is shared).
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
PLAIN = ('pastel', 'white', 'grey', 'dark')  # balls without a strong hue


def _scored(shots, detectors: dict) -> dict[str, dict]:
    """Run each detector as the node does (find, confirm and locate with the depth) on shots."""
    from ur_rg2_detector.scenes import MIN_VISIBLE
    from ur_rg2_vision.localize import locate_first

    results = {name: {'balls': 0, 'found': 0, 'false': 0, 'errors': [], 'times': [],
                      'empty': 0} for name in detectors}
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        for shot in shots:
            counted = shot.centre is not None and shot.visible >= MIN_VISIBLE
            for name, detector in detectors.items():
                result = results[name]
                start = cv2.getTickCount()
                position = locate_first(detector.detect(shot.rgb, shot.k, shot.depth), shot.depth,
                                         shot.k)
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


def _rows(label: str, r: dict, load: str, targets: tuple[str, str, str, str]
          ) -> list[tuple[str, str, str]]:
    recall, false, error, time = targets
    return [
        (f'{label}, balls found', f'{r["found"]} of {r["balls"]} '
         f'({100 * r["found"] / max(r["balls"], 1):.1f}%)', recall),
        (f'{label}, false balls', f'{r["false"]} (in {len(r["times"])} frames, {r["empty"]} '
         'without a ball)', false),
        (f'{label}, 3D error, mm median / p95',
         f'{percentile(r["errors"], 50):.2f} / {percentile(r["errors"], 95):.2f}', error),
        (f'{label}, detection + 3D per 640x480 frame, one thread, ms p50 / p95',
         f'{percentile(r["times"], 50):.1f} / {percentile(r["times"], 95):.1f} (load {load})',
         time),
    ]


def run() -> list[tuple[str, str, str]]:
    """Measure both detectors; return benchmark rows (metric, measured, target)."""
    from ur_rg2_detector.scenes import hard_scenes
    from ur_rg2_vision.detector import BallDetector
    from ur_rg2_vision.learned import (
        MODEL_FILE,
        SETTINGS_FILE,
        SHIPPED_MODEL,
        BallModel,
        LearnedBallDetector,
    )

    learned = LearnedBallDetector(BallModel(), 4.0)
    targets = ('>= 95%', '0', 'median <= 5 mm', 'p95 <= 30 ms')
    rows = []
    load_before = os.getloadavg()[0]
    results = _scored(hard_scenes(HARD_FRAMES, SEED),
                      {'color': BallDetector(), 'learned': learned})
    load = f'{load_before:.1f}-{os.getloadavg()[0]:.1f}'
    hard = f'hard set ({HARD_FRAMES} frames, seed {SEED})'
    rows += _rows(f'detector color: {hard}', results['color'], load, ('', '', '', ''))
    rows += _rows(f'detector learned: {hard}', results['learned'], load, targets)
    load_before = os.getloadavg()[0]
    plain = _scored(hard_scenes(HARD_FRAMES, SEED + 1, groups=PLAIN), {'learned': learned})
    load = f'{load_before:.1f}-{os.getloadavg()[0]:.1f}'
    rows += _rows(f'detector learned: plain balls ({", ".join(PLAIN)}; {HARD_FRAMES} frames, '
                  f'seed {SEED + 1})', plain['learned'], load, targets)
    settings = json.loads((SHIPPED_MODEL / SETTINGS_FILE).read_text())
    training, validation = settings['training'], settings['validation']
    size = os.path.getsize(SHIPPED_MODEL / MODEL_FILE) / 1e6
    records = [training]  # then what trained each --init model it started from
    while 'init' in records[-1]:
        records.append(records[-1]['init']['training'])
    minutes = [record['seconds'] / 60 for record in reversed(records)]
    spent = f'{sum(minutes):.1f} min' + (
        ' in all: ' + ' + '.join(f'{m:.1f}' for m in minutes) + ' min (--init)'
        if len(minutes) > 1 else '')
    loads = [record['load_average'] for record in records]
    _, default = _render_frames()
    pipeline = _pipeline(default, {'detector': 'learned'})
    load_pipeline = os.getloadavg()[0]
    rows += [
        ('detector learned: colour stamp -> ball/position in another process, ms p50 / p95',
         f'{pipeline["p50"]:.1f} / {pipeline["p95"]:.1f} (load {load_pipeline:.1f})',
         'p95 <= 33 ms'),
        ('detector learned: frames processed, fed at 30 Hz (ball/position)',
         f'{pipeline["positions"]} of {pipeline["sent"]} (load {load_pipeline:.1f})', 'all'),
        ('detector learned: shipped model, training time (train_detector, this machine)',
         f'{spent} ({sum(record["epochs"] for record in records)} epochs, imgsz '
         f'{training["imgsz"]}, load {min(load["start"] for load in loads)}-'
         f'{max(load["end"] for load in loads)})', '<= 60 min'),
        ('detector learned: shipped model, size (model.onnx)', f'{size:.1f} MB', 'a few MB'),
        ('detector learned: shipped model, its validation split (evaluate_detector)',
         f'recall {validation["recall"]:.3f} precision {validation["precision"]:.3f} '
         f'mAP50 {validation["mAP50"]:.3f} over {validation["images"]} images', ''),
    ]
    return rows


if __name__ == '__main__':
    from bench.__main__ import print_table

    print_table(run())
