"""``train_detector``: train a one-class YOLO ball detector on a ``dataset`` directory.

Trains ultralytics' YOLOv8 (thin scale, :file:`detector_models/yolov8t-ball.yaml`) from
scratch on the CPU, on the data set's ``data.yaml``, with ultralytics' progress bars. Writes to
``--out``: ``model.onnx`` (ultralytics' ONNX export, 1 x 5 x N, for 640x480 frames letterboxed
to ``--imgsz`` wide), ``detector.json`` (input size, class names, thresholds, the validation
metrics of the exported model as ``vision`` runs it, the training's settings and time),
``results.csv`` (ultralytics' per-epoch losses and metrics) and ``training_curve.png``; the
machine's load average is recorded beside the time (the machine may be shared). Needs
the learning set-up (``scripts/bootstrap requirements-learning.txt``).
"""

from __future__ import annotations

import argparse
import io
import json
import math
import os
from pathlib import Path
import shutil
import sys
import tempfile
import time

from ur_rg2_vision.learned import MODEL_FILE, SETTINGS_FILE, BallModel

from ur_rg2_learning.actor import write_atomically
from ur_rg2_learning.evaluate_detector import evaluate, split_images

NETWORK = Path(__file__).resolve().parent / 'detector_models' / 'yolov8t-ball.yaml'
# A box may be a ball from this class score on; the depth then decides (localize: a cube or a
# disc is no sphere). Low, for recall: on the shipped model's validation split the boxes' recall
# was 0.68 at 0.1, 0.30 at 0.25 (Ultralytics' predict default), 0.02 at 0.5.
CONFIDENCE = 0.1
IOU = 0.5  # non-maximum suppression
FRAME_ASPECT = 480 / 640  # the camera's frames: the export's input fits them
STRIDE = 32  # YOLOv8's largest stride: input sides are multiples of it
HUE_SHIFT = 0.5  # Ultralytics' hsv_h: a fraction of the hue circle (its default 0.015)
# Of Ultralytics' default 3: a run within an hour on two cores has about a dozen epochs.
WARMUP_EPOCHS = 1.0
CLOSE_MOSAIC_SHARE = 0.15  # the last epochs train on whole frames, as vision sees them


def _size_close_mosaic(trainer) -> None:
    """Keep the epochs without mosaic a share of the run, also when a time budget sets it.

    With ``--hours`` Ultralytics re-estimates the number of epochs after the first one; a
    ``close_mosaic`` fixed from ``--epochs`` could then exceed the run and switch mosaic off
    from the start.
    """
    trainer.args.close_mosaic = max(1, round(CLOSE_MOSAIC_SHARE * trainer.epochs))


def _torchvision_beside_cpu_torch() -> None:
    """Let ultralytics import torchvision beside the CPU build of torch.

    PyPI's torchvision is built against PyPI's (CUDA) torch: its compiled operators do not
    load beside torch 2.13.0+cpu, and importing it then fails ('operator torchvision::nms does
    not exist'). Ultralytics imports it for validation and uses only its box NMS: define
    that operator here, computed by ultralytics' own pure-torch NMS, before torchvision loads.
    """
    import torch
    if 'torchvision' in sys.modules or hasattr(torch.ops.torchvision, 'nms'):
        return
    library = torch.library.Library('torchvision', 'DEF')  # noqa: TOR901 - kept below
    library.define('nms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor')
    library.define('qnms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor')

    def nms(boxes, scores, threshold):
        from ultralytics.utils.nms import TorchNMS
        return TorchNMS.nms(boxes, scores, threshold)

    library.impl('nms', nms, 'CPU')
    _torchvision_beside_cpu_torch.library = library  # the definitions live as long as it
    import torchvision.extension
    torchvision.extension._has_ops = lambda: True


def plot_curve(results_csv: Path, png: Path) -> None:
    """Draw the training curve: losses and validation mAP50 / recall per epoch."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    import polars
    table = polars.read_csv(results_csv)
    table.columns = [name.strip() for name in table.columns]
    figure, (losses, metrics) = plt.subplots(1, 2, figsize=(9, 3.4))
    for name in ('train/box_loss', 'train/cls_loss', 'val/box_loss', 'val/cls_loss'):
        losses.plot(table['epoch'], table[name], label=name)
    losses.set_xlabel('epoch')
    losses.set_title('losses')
    losses.legend(fontsize=8)
    for name in ('metrics/mAP50(B)', 'metrics/recall(B)', 'metrics/precision(B)'):
        metrics.plot(table['epoch'], table[name], label=name.split('/')[1])
    metrics.set_ylim(0, 1.02)
    metrics.set_xlabel('epoch')
    metrics.set_title('validation (ultralytics, PyTorch model)')
    metrics.legend(fontsize=8, loc='lower right')
    figure.tight_layout()
    buffer = io.BytesIO()
    figure.savefig(buffer, format='png', dpi=90)
    plt.close(figure)
    write_atomically(png, lambda f: f.write(buffer.getvalue()))


def main(argv: list[str] | None = None) -> int:
    """Train, export, score; exit code 0, 2 on bad input or without the learning set-up."""
    parser = argparse.ArgumentParser(
        prog='train_detector', description=__doc__.split('\n')[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument('--data', required=True, metavar='DIR',
                        help='data set directory (dataset --out) with its data.yaml')
    parser.add_argument('--out', required=True, metavar='DIR', help='model directory to write')
    parser.add_argument('--epochs', type=int, default=40)
    parser.add_argument('--imgsz', type=int, default=320,
                        help='training image size; the export takes frames this wide')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--batch', type=int, default=16)
    parser.add_argument('--threads', type=int, default=2, help='torch CPU threads')
    parser.add_argument('--hours', type=float, default=0.0,
                        help='a time budget instead: ultralytics fits the number of epochs '
                        'to it after the first one (0: --epochs decides)')
    args = parser.parse_args(argv)
    if args.epochs < 1 or args.imgsz < STRIDE or args.imgsz % STRIDE or args.batch < 1:
        parser.error(f'--epochs and --batch must be positive, --imgsz a multiple of {STRIDE}')
    data_yaml = Path(args.data) / 'data.yaml'
    if not data_yaml.is_file():
        print(f'train_detector: no data.yaml in {args.data} (make one with dataset --out)',
              file=sys.stderr)
        return 2
    # Ultralytics' settings and font cache in a scratch directory, never online.
    scratch = Path(tempfile.mkdtemp(prefix='train_detector-'))
    os.environ.setdefault('YOLO_CONFIG_DIR', str(scratch / 'config'))
    os.environ.setdefault('YOLO_OFFLINE', '1')
    try:
        import torch
        _torchvision_beside_cpu_torch()
        import ultralytics
        from ultralytics import YOLO
    except ImportError as error:
        print(f'train_detector needs the learning set-up ({error}): run '
              '`scripts/bootstrap requirements-learning.txt`', file=sys.stderr)
        return 2
    torch.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    load_start = os.getloadavg()[0]
    started = time.monotonic()
    try:
        model = YOLO(str(NETWORK), task='detect')
        model.add_callback('on_train_epoch_start', _size_close_mosaic)
        model.train(data=str(data_yaml.resolve()), epochs=args.epochs, imgsz=args.imgsz,
                    batch=args.batch, seed=args.seed, deterministic=True, device='cpu',
                    workers=0, amp=False, plots=False, project=str(scratch), name='train',
                    exist_ok=True, verbose=False, patience=args.epochs,
                    close_mosaic=max(1, args.epochs // 5), time=args.hours or None,
                    # A ball is a ball in any colour: hue shifted by up to half the circle.
                    hsv_h=HUE_SHIFT, warmup_epochs=WARMUP_EPOCHS,
                    cache='ram')  # decoded once: PNG decoding took a third of the time
        seconds = time.monotonic() - started
        load = {'start': round(load_start, 1), 'end': round(os.getloadavg()[0], 1),
                'end_15min': round(os.getloadavg()[2], 1)}
        run = scratch / 'train'
        best = YOLO(str(run / 'weights' / 'best.pt'), task='detect')
        height = math.ceil(args.imgsz * FRAME_ASPECT / STRIDE) * STRIDE
        onnx = Path(best.export(format='onnx', imgsz=[height, args.imgsz], opset=12,
                                simplify=False, dynamic=False))
        shutil.copyfile(onnx, out / (MODEL_FILE + '.tmp'))
        os.replace(out / (MODEL_FILE + '.tmp'), out / MODEL_FILE)
        shutil.copyfile(run / 'results.csv', out / 'results.csv')
        plot_curve(out / 'results.csv', out / 'training_curve.png')
        epochs = len((out / 'results.csv').read_text().strip().splitlines()) - 1  # trained
        settings = {
            'input_size': [height, args.imgsz],
            'names': ['ball'],
            'ball_class': 0,
            'confidence': CONFIDENCE,
            'iou': IOU,
            'layout': 'ultralytics YOLOv8 ONNX: 1 x (4 + classes) x N, cx cy w h in input '
                      'pixels of the letterboxed frame',
            'training': {'data': str(Path(args.data).resolve()), 'epochs': epochs,
                         'imgsz': args.imgsz, 'seed': args.seed, 'batch': args.batch,
                         'seconds': round(seconds, 1), 'load_average': load,
                         'command': ' '.join(['train_detector', *sys.argv[1:]]
                                             if argv is None else ['train_detector', *argv]),
                         'network': NETWORK.name,
                         'library': f'ultralytics {ultralytics.__version__} (AGPL-3.0)',
                         'torch': torch.__version__},
        }
        text = json.dumps(settings, indent=2) + '\n'
        write_atomically(out / SETTINGS_FILE, lambda f: f.write(text.encode()))
        # The validation metrics of the exported model, run as the vision node runs it.
        scores = evaluate(BallModel(out).boxes, split_images(args.data, 'val'))
        settings['validation'] = {'recall': round(scores.recall, 4),
                                  'precision': round(scores.precision, 4),
                                  'mAP50': round(scores.map50, 4), 'images': scores.images}
        text = json.dumps(settings, indent=2) + '\n'
        write_atomically(out / SETTINGS_FILE, lambda f: f.write(text.encode()))
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    print(f'train_detector: {epochs} epochs in {seconds / 60:.1f} min; validation '
          f'{scores.line()}; model written to {out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
