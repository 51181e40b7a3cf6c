"""Write the ball detector's data set from rendered scenes, without a running sim. No ROS.

``python -m ur_rg2_detector.scene_dataset --count N --out DIR [--seed S]``
(``scripts/detector-data``) renders :func:`ur_rg2_detector.labelled_scenes.detector_scenes`
with the sim's own world and camera and writes the ``dataset`` layout (``images``, ``labels``
in YOLO format, ``data.yaml``) plus, per sample, ``depth/SPLIT/NAME.png`` (16-bit, millimetres,
0 = no return) and ``meta/SPLIT/NAME.json`` (colour group, camera matrix, the ball's centre in
the optical frame and radius, m): what ``evaluate_detector`` needs to run the vision node's
whole pipeline per colour group. A run appends to what is there; interrupted, every image has
its label.
"""

import argparse
import json
import sys

from ur_rg2_sim.camera import choose_renderer
from ur_rg2_vision.dataset import DatasetWriter, Progress, depth_png

from ur_rg2_detector.labelled_scenes import detector_scenes


def main(argv: list[str] | None = None) -> int:
    """Render and write ``--count`` samples; exit 0."""
    parser = argparse.ArgumentParser(prog='scene_dataset', description=__doc__.split('\n')[0])
    parser.add_argument('--count', type=int, required=True)
    parser.add_argument('--out', required=True, metavar='DIR')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--val-fraction', type=float, default=0.15)
    parser.add_argument('--progress-every', type=int, default=100)
    args = parser.parse_args(argv)
    renderer = choose_renderer('auto').name
    if renderer == 'egl':
        renderer += ' (patterned balls: tiny)'
    writer = DatasetWriter(args.out, args.val_fraction, renderer)
    progress = Progress(args.count, every=args.progress_every)
    for sample in detector_scenes(args.count, args.seed):
        shot = sample.shot
        height, width = shot.rgb.shape[:2]
        label = None
        if sample.box is not None:
            u0, v0, u1, v1 = sample.box
            label = ((u0 + u1) / 2 / width, (v0 + v1) / 2 / height, (u1 - u0) / width,
                     (v1 - v0) / height)
        meta = {'group': sample.group, 'k': shot.k.tolist(),
                'centre': None if shot.centre is None else [float(c) for c in shot.centre],
                'radius': shot.radius, 'visible': round(shot.visible, 3)}
        writer.write(shot.rgb, label, {'depth': ('.png', depth_png(shot.depth)),
                                       'meta': ('.json', json.dumps(meta).encode())})
        progress.advance()
    return 0


if __name__ == '__main__':
    sys.exit(main())
