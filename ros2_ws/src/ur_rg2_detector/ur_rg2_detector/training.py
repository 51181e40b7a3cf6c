"""One training run of the ball detector: the epochs, the choice of the best, its export.

:func:`train` trains :class:`ur_rg2_detector.detector_net.BallNet` on the frames of
:mod:`ur_rg2_detector.crops` with a cosine learning rate over a time budget or a number of
epochs, scores each epoch's export on validation frames as the vision node runs it, and
writes the best epoch's model, its ``detector.json``, ``results.csv`` and the training curve.
torch is imported only when a run starts.
"""

from __future__ import annotations

import argparse
import csv
from dataclasses import dataclass, field
import io
import json
import math
import os
from pathlib import Path
import shutil
import sys
import time

import numpy as np
from ur_rg2_learning.actor import write_atomically
from ur_rg2_vision.learned import MODEL_FILE, SETTINGS_FILE, SINGLE_PASS_FILE, BallModel
from ur_rg2_vision.learned_input import DEPTH_RELIEF, RGB, input_channels

from ur_rg2_detector.crops import (
    HARD_SCORE,
    augment,
    hard_negatives,
    load_split,
    network_input,
    plain_pairs,
)
from ur_rg2_detector.evaluate_detector import Scores, evaluate, split_images

# A box is a ball from this peak score on while training; the node's threshold (in
# detector.json) is then chosen on the validation split (best F1, see choose_threshold).
CONFIDENCE = 0.3
FLOOR = 0.05  # scores below this are never a ball
IOU = 0.5  # non-maximum suppression (one peak per ball already: a guard only)
FRAME_ASPECT = 480 / 640  # the camera's frames
VAL_FRAMES = 200  # validation frames scored after each epoch (all of them at the end)
HARD_EVERY = 20  # epochs between two minings of hard negatives
CALIBRATION_FRAMES = 64  # set the batch norms of a network loaded from its export (--init)


class TrainError(Exception):
    """The run cannot start: unreadable frames, a split without images, a bad --init."""


@dataclass
class Frames:
    """The frames of a run: training frames in memory, validation frames as files."""

    train_pairs: list[tuple[Path, Path]]
    val_pairs: list[tuple[Path, Path]]
    val_check: list[tuple[Path, Path]]  # scored after each epoch
    images: np.ndarray
    reliefs: np.ndarray | None
    boxes: list
    dropped: int  # samples dropped for their low contrast


@dataclass
class History:
    """What the epochs did: a row per epoch, the best epoch's weights, the minings."""

    rows: list[dict] = field(default_factory=list)
    best: float = -1.0
    best_state: dict | None = None
    best_epoch: int = 0
    mined: list[dict] = field(default_factory=list)


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

    ``flip``: with the flip test (:class:`ur_rg2_detector.detector_net.Exported`), and the
    network on the frame alone beside it (``SINGLE_PASS_FILE``), which the node runs first.

    Returns it loaded as the vision node loads it: scoring it scores what the node runs
    (ONNX Runtime, the frame scaled as the node scales it, non-maximum suppression).
    """
    from ur_rg2_detector.detector_net import Exported

    directory.mkdir(parents=True, exist_ok=True)
    net.eval()
    channels = input_channels(settings['inputs'])
    exports = {MODEL_FILE: flip}
    if flip:
        exports[SINGLE_PASS_FILE] = False
    else:
        (directory / SINGLE_PASS_FILE).unlink(missing_ok=True)  # of an export with the test
    for name, flipped in exports.items():
        temporary = directory / (name + '.tmp')
        torch.onnx.export(Exported(net, flipped), (torch.zeros(1, channels, *size),),
                          str(temporary), dynamo=False, opset_version=13,
                          input_names=['images'], output_names=['output'])
        os.replace(temporary, directory / name)
    write_atomically(directory / SETTINGS_FILE,
                     lambda f: f.write((json.dumps(settings, indent=2) + '\n').encode()))
    return BallModel(directory)



def load_frames(args: argparse.Namespace, rng: np.random.Generator, size: tuple[int, int]
                ) -> Frames:
    """Return the run's frames (``--epochs 0``: only those that calibrate the loaded network)."""
    started = time.monotonic()
    train_pairs, val_pairs = split_images(args.data, 'train'), split_images(args.data, 'val')
    if not train_pairs or not val_pairs:
        raise TrainError(f'{args.data} needs train and val images')
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
        raise TrainError(str(error)) from error
    val_check = [val_pairs[i] for i in np.linspace(0, len(val_pairs) - 1, min(
        VAL_FRAMES, len(val_pairs))).astype(int)]
    print(f'train_detector: {len(images)} training frames loaded in '
          f'{time.monotonic() - started:.0f} s', flush=True)
    return Frames(train_pairs, val_pairs, val_check, images, reliefs, boxes, dropped)


def start_network(torch, args: argparse.Namespace, rng: np.random.Generator, frames: Frames,
                  inputs: list[str]) -> tuple[object, dict]:
    """Return a new network, or the ``--init`` model's, and that model's detector.json."""
    from ur_rg2_detector.detector_net import BallNet, load_exported

    net = BallNet(in_channels=input_channels(inputs))
    if not args.init:
        return net, {}
    images, reliefs = frames.images, frames.reliefs
    chosen = rng.choice(len(images), min(CALIBRATION_FRAMES, len(images)), replace=False)
    calibration = torch.from_numpy(np.stack([
        network_input(images[i], None if reliefs is None else reliefs[i])
        for i in chosen]).transpose(0, 3, 1, 2))
    try:
        load_exported(net, str(Path(args.init) / MODEL_FILE), calibration)
        return net, json.loads((Path(args.init) / SETTINGS_FILE).read_text())
    except (OSError, ValueError) as error:
        raise TrainError(f'--init {args.init}: {error}') from error


def train_epoch(torch, net, optimizer, args: argparse.Namespace, rng: np.random.Generator,
                frames: Frames, hard: list, epoch: int, started: float) -> tuple[float, float]:
    """Run one epoch's steps; return its mean heat and box losses."""
    from ur_rg2_detector.detector_net import loss, targets

    net.train()
    steps = max(1, len(frames.images) // args.batch)
    order = rng.permutation(len(frames.images))
    crop = (args.crop, args.crop)
    sums = [0.0, 0.0]
    for step in range(steps):
        # Cosine over the budget, by time or by steps, whichever is further on.
        progress = max((time.monotonic() - started) / (args.minutes * 60),
                       ((epoch - 1) * steps + step) / (args.epochs * steps))
        for group in optimizer.param_groups:
            group['lr'] = args.lr * (0.02 + 0.98 * 0.5 * (1 + math.cos(
                math.pi * min(progress, 1.0))))
        batch = [augment(rng, frames.images[i], frames.boxes[i], crop,
                         None if frames.reliefs is None else frames.reliefs[i], hard[i],
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
    return sums[0] / steps, sums[1] / steps


def mine(torch, net, args: argparse.Namespace, frames: Frames, history: History, hard: list,
         epoch: int, started: float) -> list:
    """Return the frames' hard negatives when it is time to mine them again, else ``hard``."""
    progress = max((time.monotonic() - started) / (args.minutes * 60),
                   (epoch - 1) / args.epochs)
    if not (args.hard_negatives > 0 and progress >= args.hard_from and (
            not history.mined or epoch - history.mined[-1]['epoch'] >= HARD_EVERY)):
        return hard
    hard = hard_negatives(torch, net, frames.images, frames.reliefs, frames.boxes)
    history.mined.append({'epoch': epoch, 'peaks': int(sum(len(h) for h in hard)),
                          'frames': int(sum(bool(len(h)) for h in hard))})
    print(f'train_detector: epoch {epoch}: {history.mined[-1]["peaks"]} hard negatives in '
          f'{history.mined[-1]["frames"]} of {len(frames.images)} training frames', flush=True)
    return hard


def record_epoch(history: History, net, epoch: int, losses: tuple[float, float],
                 scores: Scores, started: float) -> None:
    """Add an epoch's row (printed) to ``history``; keep its weights if it is the best yet."""
    f1 = 2 * scores.recall * scores.precision / max(scores.recall + scores.precision, 1e-9)
    minutes = (time.monotonic() - started) / 60
    row = {'epoch': epoch, 'minutes': round(minutes, 2), 'heat_loss': round(losses[0], 5),
           'box_loss': round(losses[1], 5), 'recall': round(scores.recall, 4),
           'precision': round(scores.precision, 4), 'mAP50': round(scores.map50, 4),
           'load': round(os.getloadavg()[0], 1)}
    history.rows.append(row)
    print(f'epoch {epoch} ({minutes:.1f} min, load {row["load"]}): heat loss '
          f'{row["heat_loss"]} box loss {row["box_loss"]}; validation '
          f'{scores.line()}', flush=True)
    if f1 + scores.map50 > history.best:
        history.best = f1 + scores.map50
        history.best_state = {k: v.clone() for k, v in net.state_dict().items()}
        history.best_epoch = epoch


def fit(torch, net, args: argparse.Namespace, rng: np.random.Generator, frames: Frames,
        settings: dict, scratch: Path, started: float) -> History:
    """Train for ``--epochs`` or ``--minutes``; return the history, the best weights loaded."""
    optimizer = torch.optim.AdamW(net.parameters(), lr=args.lr, weight_decay=1e-4)
    size = tuple(settings['input_size'])
    history = History()
    hard: list[np.ndarray | None] = [None] * len(frames.images)
    for epoch in range(1, args.epochs + 1):
        net.train()
        hard = mine(torch, net, args, frames, history, hard, epoch, started)
        losses = train_epoch(torch, net, optimizer, args, rng, frames, hard, epoch, started)
        scores = evaluate(export(torch, net, size, scratch, dict(
            settings, confidence=CONFIDENCE), args.flip_test).boxes, frames.val_check)
        record_epoch(history, net, epoch, losses, scores, started)
        if time.monotonic() - started >= args.minutes * 60:
            break
    if history.best_state is not None:
        net.load_state_dict(history.best_state)
    return history


def write_curve(rows: list[dict], out: Path, init: str | None) -> None:
    """Write ``results.csv`` and the curve; exported again, copy the ``--init`` model's."""
    if rows:
        text = io.StringIO()
        writer = csv.DictWriter(text, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
        write_atomically(out / 'results.csv', lambda f: f.write(text.getvalue().encode()))
        plot_curve(rows, out / 'training_curve.png')
        return
    for name in ('results.csv', 'training_curve.png'):
        if (Path(init) / name).is_file():
            shutil.copyfile(Path(init) / name, out / name)


def training_record(torch, args: argparse.Namespace, frames: Frames, history: History,
                    seconds: float, load: dict, init_settings: dict) -> dict:
    """Return ``detector.json``'s ``training``: the options, data, time, load and network."""
    record = {'data': str(Path(args.data).resolve()), 'epochs': len(history.rows),
              'best_epoch': history.best_epoch, 'imgsz': args.imgsz, 'crop': args.crop,
              'seed': args.seed, 'batch': args.batch, 'lr': args.lr,
              'frames': len(frames.train_pairs), 'val_frames': len(frames.val_pairs),
              'dropped_low_contrast': frames.dropped,
              'hard_negatives': {'share': args.hard_negatives, 'from': args.hard_from,
                                 'score': HARD_SCORE, 'mined': history.mined},
              'seconds': round(seconds, 1),
              'load_average': load,
              'command': args.command,
              'network': 'ur_rg2_detector.detector_net.BallNet',
              'library': f'torch {torch.__version__} (BSD-3-Clause)'}
    if args.init:  # what trained the weights it started from
        record['init'] = {'model': str(Path(args.init).resolve()), **{
            k: v for k, v in init_settings.items() if k in ('training', 'validation')}}
    return record


def train(args: argparse.Namespace) -> int:
    """Train, export and score one seed as ``args`` (``main``'s options) say; exit code."""
    import torch

    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    size = (round(args.imgsz * FRAME_ASPECT), args.imgsz)
    started = time.monotonic()
    load_start = os.getloadavg()[0]
    inputs = [RGB, DEPTH_RELIEF] if args.depth else [RGB]
    try:
        frames = load_frames(args, rng, size)
        net, init_settings = start_network(torch, args, rng, frames, inputs)
    except TrainError as error:
        print(f'train_detector: {error}', file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scratch = out / '.epoch'  # each epoch's export, scored as the node runs it
    settings = {'input_size': list(size), 'names': ['ball'], 'ball_class': 0, 'iou': IOU,
                'inputs': inputs, 'flip_test': args.flip_test}
    history = fit(torch, net, args, rng, frames, settings, scratch, started)
    seconds = time.monotonic() - started
    load = {'start': round(load_start, 1), 'end': round(os.getloadavg()[0], 1),
            'end_15min': round(os.getloadavg()[2], 1)}
    scored = evaluate(export(torch, net, size, scratch, dict(settings, confidence=FLOOR),
                             args.flip_test).boxes, frames.val_pairs)
    confidence = choose_threshold(scored.ranked, scored.balls)
    shutil.rmtree(scratch, ignore_errors=True)
    write_curve(history.rows, out, args.init)
    settings.update({
        'confidence': confidence,
        'layout': 'ur_rg2_detector.detector_net (CenterNet, stride 8) ONNX: 1 x 5 x N rows cx '
                  'cy w h score in input pixels of the frame scaled to the input',
        'licence': 'Apache-2.0 (trained by this project, from scratch{})'.format(
            f', then further from {args.init}' if args.init and history.rows else ''),
        'training': training_record(torch, args, frames, history, seconds, load,
                                    init_settings),
    })
    # The validation metrics of the exported model, run as the vision node runs it.
    scores = evaluate(export(torch, net, size, out, settings, args.flip_test).boxes,
                      frames.val_pairs)
    settings['validation'] = {'recall': round(scores.recall, 4),
                              'precision': round(scores.precision, 4),
                              'mAP50': round(scores.map50, 4), 'images': scores.images}
    write_atomically(out / SETTINGS_FILE,
                     lambda f: f.write((json.dumps(settings, indent=2) + '\n').encode()))
    print(f'train_detector: {len(history.rows)} epochs in {seconds / 60:.1f} min (load '
          f'{load["start"]} at the start, {load["end"]} at the end), '
          f'{(time.monotonic() - started) / 60:.1f} min with the export and validation; best '
          f'epoch {history.best_epoch}; threshold {confidence}; validation {scores.line()}; '
          f'model written to {out}')
    return 0
