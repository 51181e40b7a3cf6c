"""``train_detector``: train the one-class ball detector on a ``dataset`` directory.

Trains :class:`ur_rg2_detector.detector_net.BallNet` (a compact CenterNet written for this
project in plain torch, Apache-2.0; no pretrained weights, no detection library) from scratch
on the CPU, or further from a model it exported (``--init``), on the data set's ``data.yaml``
(YOLO layout); with ``--depth`` the network also sees each frame's depth relief
(:func:`ur_rg2_vision.learned_input.depth_relief`). The frames and their crops:
:mod:`ur_rg2_detector.crops`; the run, the best epoch's export and what it writes to ``--out``
(``model.onnx``, ``detector.json``, ``results.csv``, ``training_curve.png``):
:mod:`ur_rg2_detector.training`. ``--seeds A B ...`` trains each seed as a Ray task and writes
``seed_N/`` for each and ``seeds.md``, their validation side by side. Needs the learning set-up
(``scripts/bootstrap requirements-learning.txt``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys
import tempfile

from ur_rg2_learning.actor import write_atomically
from ur_rg2_learning.ray_tasks import markdown_table
from ur_rg2_vision.learned import SETTINGS_FILE

from ur_rg2_detector.training import FRAME_ASPECT, HARD_EVERY, train


def build_parser() -> argparse.ArgumentParser:
    """Return the command line's parser."""
    parser = argparse.ArgumentParser(
        prog='train_detector', description=__doc__.split('\n')[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument('--data', required=True, metavar='DIR',
                        help='data set directory (dataset --out) with its data.yaml')
    parser.add_argument('--out', required=True, metavar='DIR', help='model directory to write')
    parser.add_argument('--epochs', type=int, default=60,
                        help='0 with --init: no training, the --init model is exported again '
                        "(with this run's --flip-test), scored and its threshold chosen")
    parser.add_argument('--minutes', type=float, default=50.0,
                        help='time budget: training ends after it even before --epochs')
    parser.add_argument('--imgsz', type=int, default=320,
                        help='input width (a multiple of 32); the height keeps 4:3')
    parser.add_argument('--crop', type=int, default=128, help='training crop side, pixels')
    seeds = parser.add_mutually_exclusive_group()
    seeds.add_argument('--seed', type=int, default=0, help='one seed, in this process')
    seeds.add_argument('--seeds', type=int, nargs='+', metavar='SEED',
                       help='several seeds, each a Ray task: writes seed_N/ for each and '
                       'seeds.md, their validation side by side')
    parser.add_argument('--num-cpus', type=int, default=None,
                        help='with --seeds: CPUs of the local Ray (default: all)')
    parser.add_argument('--address', default=None,
                        help='with --seeds: an existing Ray cluster (auto or HOST:PORT; its '
                        'workers need --data and --init at the same paths)')
    parser.add_argument('--batch', type=int, default=64)
    parser.add_argument('--lr', type=float, default=3e-3)
    parser.add_argument('--init', metavar='MODEL_DIR',
                        help='start from the weights of a model directory (its model.onnx) '
                        'instead of from scratch')
    parser.add_argument('--min-contrast', type=float, default=0.0, metavar='V',
                        help='drop the samples (train and val) whose ball is within V of its '
                        "surroundings' value (0-1; 0.05: dark on dark)")
    parser.add_argument('--depth', action='store_true',
                        help="the network also sees the depth's relief (a fourth channel; "
                        "needs scene_dataset's depth/ images beside the data set's)")
    parser.add_argument('--hard-negatives', type=float, default=0.3, metavar='SHARE',
                        help="share of the crops centred on the network's own false peaks "
                        '(hard negative mining; 0: none)')
    parser.add_argument('--hard-from', type=float, default=0.25, metavar='PROGRESS',
                        help='part of the training (0-1) after which hard negatives are mined, '
                        f'then every {HARD_EVERY} epochs')
    parser.add_argument('--flip-test', action='store_true',
                        help='the exported model averages the maps of each frame and of its '
                        "mirror image (CenterNet's flip test; twice the inference time)")
    parser.add_argument('--threads', type=int, default=1,
                        help='torch CPU threads (one ran 10 times faster than two on the '
                        'shared 2-core machine)')
    return parser


def main(argv: list[str] | None = None) -> int:
    """Train, export, score; exit code 0, 2 on bad input or without the learning set-up."""
    parser = build_parser()
    args = parser.parse_args(argv)
    height = round(args.imgsz * FRAME_ASPECT)
    if (args.epochs < 0 or args.imgsz < 32 or args.imgsz % 32 or args.batch < 1
            or not 32 <= args.crop <= height or args.minutes <= 0
            or not 0 <= args.hard_negatives <= 1 or not 0 <= args.hard_from <= 1):
        parser.error('--batch and --minutes must be positive, --epochs 0 or more, --imgsz a '
                     'multiple of 32, --crop between 32 and the input height, --hard-negatives '
                     'and --hard-from between 0 and 1')
    if args.epochs == 0 and not args.init:
        parser.error('--epochs 0 exports a model again: it needs --init')
    if args.seeds is not None and len(set(args.seeds)) != len(args.seeds):
        parser.error('--seeds: each seed once')
    if not (Path(args.data) / 'data.yaml').is_file():
        print(f'train_detector: no data.yaml in {args.data} (make one with dataset --out)',
              file=sys.stderr)
        return 2
    try:
        import torch  # noqa: F401
    except ImportError as error:
        print(f'train_detector needs the learning set-up ({error}): run '
              '`scripts/bootstrap requirements-learning.txt`', file=sys.stderr)
        return 2
    args.command = ' '.join(['train_detector', *(sys.argv[1:] if argv is None else argv)])
    if args.seeds is None:
        return train(args)
    from ur_rg2_learning.ray_tasks import ray_map

    options = {k: v for k, v in vars(args).items()
               if k not in ('seeds', 'num_cpus', 'address')}
    results = ray_map(train_seed_files, [(options, seed) for seed in args.seeds],
                      args.num_cpus, args.address)
    return write_seeds(results, Path(args.out))


def train_seed_files(options: dict, seed: int) -> dict:
    """Train one seed in a directory of its own; return its exit code and files (a Ray task)."""
    with tempfile.TemporaryDirectory(prefix='train_detector_') as scratch:
        code = train(argparse.Namespace(**dict(options, seed=seed, out=scratch)))
        files = {path.name: path.read_bytes() for path in Path(scratch).iterdir()
                 if path.is_file()}
    return {'seed': seed, 'code': code, 'files': files}


def write_seeds(results: list[dict], out: Path) -> int:
    """Write each seed's model to ``out/seed_N`` and ``seeds.md``; return 0, 1 if one failed."""
    rows = [('seed', 'epochs (best)', 'minutes', 'threshold',
             'validation recall / precision / mAP50 at it')]
    for result in sorted(results, key=lambda r: r['seed']):
        folder = out / f'seed_{result["seed"]}'
        folder.mkdir(parents=True, exist_ok=True)
        for name, data in result['files'].items():
            write_atomically(folder / name, lambda f, data=data: f.write(data))
        print(f'train_detector: seed {result["seed"]}: written to {folder}')
        if result['code'] != 0 or SETTINGS_FILE not in result['files']:
            rows.append((str(result['seed']), f'failed (exit {result["code"]})', '', '', ''))
            continue
        settings = json.loads(result['files'][SETTINGS_FILE])
        training, scores = settings['training'], settings['validation']
        rows.append((str(result['seed']), f'{training["epochs"]} ({training["best_epoch"]})',
                     f'{training["seconds"] / 60:.1f}', f'{settings["confidence"]:g}',
                     f'{scores["recall"]:.3f} / {scores["precision"]:.3f} / '
                     f'{scores["mAP50"]:.3f}'))
    text = markdown_table(rows)
    write_atomically(out / 'seeds.md', lambda f: f.write(text.encode()))
    print(text, end='')
    return 0 if all(result['code'] == 0 for result in results) else 1



if __name__ == '__main__':
    sys.exit(main())
