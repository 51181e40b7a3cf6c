"""``train_detector``: train the one-class ball detector on a ``dataset`` directory.

Trains :class:`ur_rg2_learning.detector_net.BallNet` (a compact CenterNet written for this
project in plain torch, Apache-2.0; no pretrained weights, no detection library) from scratch
on the CPU, or further from a model it exported (``--init``), on the data set's ``data.yaml``
(YOLO layout; ``--min-contrast`` drops the balls that do not stand out). With ``--depth`` the
network also sees each frame's depth relief (:func:`ur_rg2_vision.learned.depth_relief`, from
the ``depth/`` images ``scripts/detector-data`` writes) as a fourth channel. Frames are scaled
to the input size (``--imgsz`` wide, 4:3) and held in memory; each step trains on random crops
of them (``--crop``; the network is fully convolutional), flipped, with their colour channels
shuffled and their brightness and contrast changed. From ``--hard-from`` of the training on,
every few epochs the network is run on the whole training frames and its false peaks (a score
of at least 0.1 outside the frame's ball) are kept as hard negatives: ``--hard-negatives`` of
the crops are then centred on one of them, so the network learns what it takes for a ball
(hard negative mining). The learning rate follows a cosine over
``--minutes`` (a time budget: the machine may be shared) or ``--epochs``, whichever ends
first. After each epoch the network is scored on the validation frames; the best epoch (F1 at
the node's threshold) is exported, with ``--flip-test`` as a model that averages each frame's
maps with its mirror image's (``--epochs 0 --init MODEL``: that model exported again). Writes
to ``--out``: ``model.onnx`` (1 x 5 x N rows ``cx cy w h score``, the layout
:mod:`ur_rg2_vision.learned` reads), ``detector.json`` (input size, class names, thresholds,
how it was trained, with the load average, and the validation metrics of the exported model run
as ``vision`` runs it), ``results.csv`` (per epoch) and ``training_curve.png``.
``--seeds A B ...`` trains each seed as a Ray task (a local Ray with ``--num-cpus``, or an
existing cluster with ``--address``) and writes ``seed_N/`` for each and ``seeds.md``, their
validation side by side. Needs the learning set-up (``scripts/bootstrap
requirements-learning.txt``).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import os
from pathlib import Path
import shutil
import sys
import tempfile
import time

import cv2
import numpy as np
from ur_rg2_vision.learned import (
    DEPTH_RELIEF,
    MODEL_FILE,
    RGB,
    SETTINGS_FILE,
    BallModel,
    depth_relief,
    input_channels,
)

from ur_rg2_learning.actor import write_atomically
from ur_rg2_learning.evaluate_detector import evaluate, label_box, read_depth, split_images
from ur_rg2_learning.ray_tasks import markdown_table

# A box is a ball from this peak score on while training; the node's threshold (in
# detector.json) is then chosen on the validation split (best F1, see choose_threshold).
CONFIDENCE = 0.3
FLOOR = 0.05  # scores below this are never a ball
IOU = 0.5  # non-maximum suppression (one peak per ball already: a guard only)
FRAME_ASPECT = 480 / 640  # the camera's frames
VAL_FRAMES = 200  # validation frames scored after each epoch (all of them at the end)
HARD_SCORE = 0.1  # a peak from this score on outside the frame's ball is a hard negative
HARD_EVERY = 20  # epochs between two minings of hard negatives
CALIBRATION_FRAMES = 64  # set the batch norms of a network loaded from its export (--init)


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
    from ur_rg2_learning.detector_net import Exported

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


def plot_curve(rows: list[dict], png: Path) -> None:
    """Draw the training curve: losses and validation recall / precision / mAP50 per epoch."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    epochs = [row['epoch'] for row in rows]
    figure, (losses, metrics) = plt.subplots(1, 2, figsize=(9, 3.4))
    for name in ('heat_loss', 'box_loss'):
        losses.plot(epochs, [row[name] for row in rows], label=name)
    losses.set_xlabel('epoch')
    losses.set_yscale('log')
    losses.set_title('training losses')
    losses.legend(fontsize=8)
    for name in ('recall', 'precision', 'mAP50'):
        metrics.plot(epochs, [row[name] for row in rows], label=name)
    metrics.set_ylim(0, 1.02)
    metrics.set_xlabel('epoch')
    metrics.set_title(f'validation (at score {CONFIDENCE})')
    metrics.legend(fontsize=8, loc='lower right')
    figure.tight_layout()
    buffer = io.BytesIO()
    figure.savefig(buffer, format='png', dpi=90)
    plt.close(figure)
    write_atomically(png, lambda f: f.write(buffer.getvalue()))


def choose_threshold(ranked: list[tuple[float, bool]], balls: int) -> float:
    """Return the score threshold of best F1 (the higher one of equals) over ranked boxes."""
    best, threshold = -1.0, CONFIDENCE
    for t in np.arange(0.1, 0.91, 0.05):
        found = sum(right for score, right in ranked if score >= t)
        false = sum(not right for score, right in ranked if score >= t)
        f1 = 2 * found / max(found + false + balls, 1)
        if f1 >= best:
            best, threshold = f1, round(float(t), 2)
    return threshold


def export(torch, net, size: tuple[int, int], directory: Path, settings: dict,
           flip: bool = False) -> BallModel:
    """Write the network (with its decoding) as ``model.onnx`` and ``settings`` beside it.

    ``flip``: with the flip test (:class:`ur_rg2_learning.detector_net.Exported`).

    Returns it loaded as the vision node loads it: scoring it scores what the node runs
    (ONNX Runtime, the frame scaled as the node scales it, non-maximum suppression).
    """
    from ur_rg2_learning.detector_net import Exported

    directory.mkdir(parents=True, exist_ok=True)
    temporary = directory / (MODEL_FILE + '.tmp')
    net.eval()
    channels = input_channels(settings['inputs'])
    torch.onnx.export(Exported(net, flip), (torch.zeros(1, channels, *size),), str(temporary),
                      dynamo=False, opset_version=13, input_names=['images'],
                      output_names=['output'])
    os.replace(temporary, directory / MODEL_FILE)
    write_atomically(directory / SETTINGS_FILE,
                     lambda f: f.write((json.dumps(settings, indent=2) + '\n').encode()))
    return BallModel(directory)


def main(argv: list[str] | None = None) -> int:
    """Train, export, score; exit code 0, 2 on bad input or without the learning set-up."""
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


def train(args: argparse.Namespace) -> int:
    """Train, export and score one seed as ``args`` (main's options) say; exit code."""
    import torch

    from ur_rg2_learning.detector_net import BallNet, loss, targets
    height = round(args.imgsz * FRAME_ASPECT)
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    size = (height, args.imgsz)
    started = time.monotonic()
    load_start = os.getloadavg()[0]
    train_pairs, val_pairs = split_images(args.data, 'train'), split_images(args.data, 'val')
    if not train_pairs or not val_pairs:
        print(f'train_detector: {args.data} needs train and val images', file=sys.stderr)
        return 2
    dropped = 0
    if args.min_contrast > 0:
        counts = len(train_pairs) + len(val_pairs)
        train_pairs = plain_pairs(train_pairs, args.min_contrast)
        val_pairs = plain_pairs(val_pairs, args.min_contrast)
        dropped = counts - len(train_pairs) - len(val_pairs)
        print(f'train_detector: {dropped} samples dropped (ball contrast < '
              f'{args.min_contrast})', flush=True)
    loaded = train_pairs
    if args.epochs == 0:  # exported again: only the frames that calibrate the loaded network
        loaded = [train_pairs[i] for i in np.sort(rng.choice(
            len(train_pairs), min(CALIBRATION_FRAMES, len(train_pairs)), replace=False))]
    try:
        images, reliefs, boxes = load_split(loaded, size, args.depth)
    except OSError as error:
        print(f'train_detector: {error}', file=sys.stderr)
        return 2
    val_check = [val_pairs[i] for i in np.linspace(0, len(val_pairs) - 1, min(
        VAL_FRAMES, len(val_pairs))).astype(int)]
    print(f'train_detector: {len(images)} training frames loaded in '
          f'{time.monotonic() - started:.0f} s', flush=True)
    inputs = [RGB, DEPTH_RELIEF] if args.depth else [RGB]
    net = BallNet(in_channels=input_channels(inputs))
    init_settings: dict = {}  # the detector.json of the model --init starts from
    if args.init:
        from ur_rg2_learning.detector_net import load_exported
        chosen = rng.choice(len(images), min(CALIBRATION_FRAMES, len(images)), replace=False)
        calibration = torch.from_numpy(np.stack([
            network_input(images[i], None if reliefs is None else reliefs[i])
            for i in chosen]).transpose(0, 3, 1, 2))
        try:
            load_exported(net, str(Path(args.init) / MODEL_FILE), calibration)
            init_settings = json.loads((Path(args.init) / SETTINGS_FILE).read_text())
        except (OSError, ValueError) as error:
            print(f'train_detector: --init {args.init}: {error}', file=sys.stderr)
            return 2
    optimizer = torch.optim.AdamW(net.parameters(), lr=args.lr, weight_decay=1e-4)
    budget = args.minutes * 60
    steps_per_epoch = max(1, len(images) // args.batch)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scratch = out / '.epoch'  # each epoch's export, scored as the node runs it
    settings = {'input_size': list(size), 'names': ['ball'], 'ball_class': 0, 'iou': IOU,
                'inputs': inputs, 'flip_test': args.flip_test}
    rows: list[dict] = []
    best, best_state, best_epoch = -1.0, None, 0
    crop = (args.crop, args.crop)
    hard: list[np.ndarray | None] = [None] * len(images)
    mined: list[dict] = []  # when hard negatives were mined, how many
    for epoch in range(1, args.epochs + 1):
        net.train()
        progress = max((time.monotonic() - started) / budget, (epoch - 1) / args.epochs)
        if args.hard_negatives > 0 and progress >= args.hard_from and (
                not mined or epoch - mined[-1]['epoch'] >= HARD_EVERY):
            hard = hard_negatives(torch, net, images, reliefs, boxes)
            mined.append({'epoch': epoch, 'peaks': int(sum(len(h) for h in hard)),
                          'frames': int(sum(bool(len(h)) for h in hard))})
            print(f'train_detector: epoch {epoch}: {mined[-1]["peaks"]} hard negatives in '
                  f'{mined[-1]["frames"]} of {len(images)} training frames', flush=True)
        order = rng.permutation(len(images))
        sums = [0.0, 0.0]
        for step in range(steps_per_epoch):
            # Cosine over the budget, by time or by steps, whichever is further on.
            progress = max((time.monotonic() - started) / budget,
                           ((epoch - 1) * steps_per_epoch + step) / (
                               args.epochs * steps_per_epoch))
            for group in optimizer.param_groups:
                group['lr'] = args.lr * (0.02 + 0.98 * 0.5 * (1 + math.cos(
                    math.pi * min(progress, 1.0))))
            batch = [augment(rng, images[i], boxes[i], crop,
                             None if reliefs is None else reliefs[i], hard[i],
                             args.hard_negatives)
                     for i in order[step * args.batch:(step + 1) * args.batch]]
            x = torch.from_numpy(np.stack([b[0] for b in batch]).transpose(0, 3, 1, 2))
            heat, regress, index = targets([b[1] for b in batch], *crop)
            focal, box = loss(net(x), torch.from_numpy(heat), torch.from_numpy(regress),
                              torch.from_numpy(index))
            optimizer.zero_grad()
            (focal + box).backward()
            optimizer.step()
            sums[0] += float(focal.detach())
            sums[1] += float(box.detach())
        scores = evaluate(export(torch, net, size, scratch, dict(
            settings, confidence=CONFIDENCE), args.flip_test).boxes, val_check)
        f1 = 2 * scores.recall * scores.precision / max(scores.recall + scores.precision, 1e-9)
        minutes = (time.monotonic() - started) / 60
        rows.append({'epoch': epoch, 'minutes': round(minutes, 2),
                     'heat_loss': round(sums[0] / steps_per_epoch, 5),
                     'box_loss': round(sums[1] / steps_per_epoch, 5),
                     'recall': round(scores.recall, 4), 'precision': round(scores.precision, 4),
                     'mAP50': round(scores.map50, 4), 'load': round(os.getloadavg()[0], 1)})
        print(f'epoch {epoch} ({minutes:.1f} min, load {rows[-1]["load"]}): heat loss '
              f'{rows[-1]["heat_loss"]} box loss {rows[-1]["box_loss"]}; validation '
              f'{scores.line()}', flush=True)
        if f1 + scores.map50 > best:
            best = f1 + scores.map50
            best_state = {k: v.clone() for k, v in net.state_dict().items()}
            best_epoch = epoch
        if time.monotonic() - started >= budget:
            break
    seconds = time.monotonic() - started
    load = {'start': round(load_start, 1), 'end': round(os.getloadavg()[0], 1),
            'end_15min': round(os.getloadavg()[2], 1)}
    if best_state is not None:
        net.load_state_dict(best_state)
    scored = evaluate(export(torch, net, size, scratch, dict(settings, confidence=FLOOR),
                             args.flip_test).boxes, val_pairs)
    confidence = choose_threshold(scored.ranked, scored.balls)
    shutil.rmtree(scratch, ignore_errors=True)
    if rows:
        text = io.StringIO()
        writer = csv.DictWriter(text, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
        write_atomically(out / 'results.csv', lambda f: f.write(text.getvalue().encode()))
        plot_curve(rows, out / 'training_curve.png')
    else:  # exported again: the curve is the --init model's
        for name in ('results.csv', 'training_curve.png'):
            if (Path(args.init) / name).is_file():
                shutil.copyfile(Path(args.init) / name, out / name)
    settings.update({
        'confidence': confidence,
        'layout': 'ur_rg2_learning.detector_net (CenterNet, stride 8) ONNX: 1 x 5 x N rows cx '
                  'cy w h score in input pixels of the frame scaled to the input',
        'licence': 'Apache-2.0 (trained by this project, from scratch{})'.format(
            f', then further from {args.init}' if args.init and rows else ''),
        'training': {'data': str(Path(args.data).resolve()), 'epochs': len(rows),
                     'best_epoch': best_epoch, 'imgsz': args.imgsz, 'crop': args.crop,
                     'seed': args.seed, 'batch': args.batch, 'lr': args.lr,
                     'frames': len(train_pairs), 'val_frames': len(val_pairs),
                     'dropped_low_contrast': dropped,
                     'hard_negatives': {'share': args.hard_negatives, 'from': args.hard_from,
                                        'score': HARD_SCORE, 'mined': mined},
                     'seconds': round(seconds, 1),
                     'load_average': load,
                     'command': args.command,
                     'network': 'ur_rg2_learning.detector_net.BallNet',
                     'library': f'torch {torch.__version__} (BSD-3-Clause)'},
    })
    if args.init:  # what trained the weights it started from
        settings['training']['init'] = {'model': str(Path(args.init).resolve()), **{
            k: v for k, v in init_settings.items() if k in ('training', 'validation')}}
    # The validation metrics of the exported model, run as the vision node runs it.
    scores = evaluate(export(torch, net, size, out, settings, args.flip_test).boxes, val_pairs)
    settings['validation'] = {'recall': round(scores.recall, 4),
                              'precision': round(scores.precision, 4),
                              'mAP50': round(scores.map50, 4), 'images': scores.images}
    write_atomically(out / SETTINGS_FILE,
                     lambda f: f.write((json.dumps(settings, indent=2) + '\n').encode()))
    print(f'train_detector: {len(rows)} epochs in {seconds / 60:.1f} min (load '
          f'{load["start"]} at the start, {load["end"]} at the end), '
          f'{(time.monotonic() - started) / 60:.1f} min with the export and validation; best '
          f'epoch {best_epoch}; threshold {confidence}; validation {scores.line()}; model '
          f'written to {out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
