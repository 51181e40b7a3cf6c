"""The ball detector's network: a compact one-class CenterNet in plain torch (this project's).

An image goes through a small convolutional backbone (strides 2-32) and a feature pyramid
back to stride 8, where a head predicts per cell a ball-centre heatmap (focal loss, Gaussian
targets, as CenterNet: Zhou et al., "Objects as Points", 2019), the centre's sub-cell offset
and the box's log size. :class:`Exported` decodes that in the graph, so the ONNX model gives
``1 x 5 x N`` rows ``cx cy w h score`` in input pixels (``score`` 0 except at a heatmap's
local maximum): the same layout as a YOLOv8 export with one class, which
:class:`ur_rg2_vision.learned.BallModel` reads. Written for this project (Apache-2.0); no
pretrained weights. A fourth input channel, the depth's relief
(:func:`ur_rg2_vision.learned_input.depth_relief`), shows what stands out of its surroundings.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn
from torch.nn import functional

STRIDE = 8  # the output's cells, input pixels
WIDTHS = (12, 20, 32, 48, 64)  # channels at strides 2, 4, 8, 16, 32
HEAD = 32


def _conv(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.BatchNorm2d(cout),
                         nn.ReLU(inplace=True))


class BallNet(nn.Module):
    """Backbone, pyramid and head; ``forward`` gives the raw 5-channel map at stride 8.

    ``in_channels``: 3 (RGB) or 4 (RGB and the depth's relief,
    :func:`ur_rg2_vision.learned_input.depth_relief`).
    """

    def __init__(self, in_channels: int = 3) -> None:
        super().__init__()
        w = WIDTHS
        self.stem = nn.Sequential(_conv(in_channels, w[0], 2), _conv(w[0], w[1], 2))
        self.down = nn.ModuleList(
            nn.Sequential(_conv(w[i], w[i + 1], 2), _conv(w[i + 1], w[i + 1]))
            for i in range(1, len(w) - 1))
        # Top-down: each level's upsampled features added to the lateral ones, then smoothed.
        self.lateral = nn.ModuleList(nn.Conv2d(w[i], w[i], 1) for i in range(2, len(w) - 1))
        self.reduce = nn.ModuleList(nn.Conv2d(w[i + 1], w[i], 1) for i in range(2, len(w) - 1))
        self.smooth = nn.ModuleList(_conv(w[i], w[i]) for i in range(2, len(w) - 1))
        self.head = nn.Sequential(_conv(w[2], HEAD), nn.Conv2d(HEAD, 5, 1))
        # Start with a low ball probability everywhere (the focal loss's usual prior).
        nn.init.constant_(self.head[-1].bias, 0.0)
        with torch.no_grad():
            self.head[-1].bias[0] = -math.log((1 - 0.01) / 0.01)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Return the raw map (B, 5, H/8, W/8) of a batch of images (RGB 0-1, [relief])."""
        features = []
        x = self.stem(x)
        for stage in self.down:
            x = stage(x)
            features.append(x)  # strides 8, 16, 32
        top = features[-1]
        for level in range(len(features) - 2, -1, -1):
            skip = features[level]
            top = functional.interpolate(self.reduce[level](top), size=skip.shape[-2:],
                                         mode='nearest')
            top = self.smooth[level](top + self.lateral[level](skip))
        return self.head(top)


class Exported(nn.Module):
    """The network with its decoding, as exported: RGB 0-1 [and relief] in, ``1 x 5 x N`` out.

    ``flip``: the flip test of CenterNet's paper: the maps of the image and of its mirror image
    (mirrored back) are averaged before the decoding, so a peak only one view sees is weakened.
    """

    def __init__(self, net: BallNet, flip: bool = False) -> None:
        super().__init__()
        self.net = net
        self.flip = flip

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """Return (B, 5, N) rows cx cy w h score of a batch of images, as BallNet takes them."""
        if self.flip:
            count = images.shape[0]
            both = self.net(torch.cat([images, torch.flip(images, [3])]))
            out, mirrored = both[:count], torch.flip(both[count:], [3])
            heat = (torch.sigmoid(out[:, :1]) + torch.sigmoid(mirrored[:, :1])) / 2
            # A mirrored cell's x offset counts from the cell's other side.
            out = torch.cat([out[:, 1:2] + 1 - mirrored[:, 1:2], out[:, 2:5] + mirrored[:, 2:5]],
                            dim=1) / 2
        else:
            out = self.net(images)
            heat, out = torch.sigmoid(out[:, :1]), out[:, 1:5]
        peaks = heat * (functional.max_pool2d(heat, 3, 1, 1) == heat).to(heat.dtype)
        height, width = out.shape[-2:]
        ys = torch.arange(height, dtype=out.dtype).view(1, 1, height, 1).expand(1, 1, height,
                                                                                 width)
        xs = torch.arange(width, dtype=out.dtype).view(1, 1, 1, width).expand(1, 1, height,
                                                                                width)
        cx = (xs + out[:, 0:1]) * STRIDE
        cy = (ys + out[:, 1:2]) * STRIDE
        size = torch.exp(out[:, 2:4].clamp(max=6.0)) * STRIDE
        rows = torch.cat([cx, cy, size, peaks], dim=1)
        return rows.flatten(2)


def targets(boxes: list[tuple[float, float, float, float] | None], height: int, width: int
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the training targets of a batch of labels, boxes (u0, v0, u1, v1) in input px.

    Heatmaps (B, H, W) with a Gaussian at each ball's centre cell (sigma from its size),
    regressions (B, 4) (offset x, y within the cell, log w, log h in cells) and the centre
    cells' flat indices (B,), -1 without a ball.
    """
    rows, cols = height // STRIDE, width // STRIDE
    heat = np.zeros((len(boxes), rows, cols), np.float32)
    regress = np.zeros((len(boxes), 4), np.float32)
    index = np.full(len(boxes), -1, np.int64)
    ys, xs = np.mgrid[0:rows, 0:cols]
    for i, box in enumerate(boxes):
        if box is None:
            continue
        u0, v0, u1, v1 = box
        cx, cy = (u0 + u1) / 2 / STRIDE, (v0 + v1) / 2 / STRIDE
        w, h = max(u1 - u0, 1.0) / STRIDE, max(v1 - v0, 1.0) / STRIDE
        col, row = min(int(cx), cols - 1), min(int(cy), rows - 1)
        sigma = max(0.5, math.sqrt(w * h) / 6)
        heat[i] = np.exp(-((xs - col) ** 2 + (ys - row) ** 2) / (2 * sigma * sigma))
        heat[i, row, col] = 1.0
        regress[i] = (cx - col, cy - row, math.log(w), math.log(h))
        index[i] = row * cols + col
    return heat, regress, index


def loss(out: torch.Tensor, heat: torch.Tensor, regress: torch.Tensor, index: torch.Tensor
         ) -> tuple[torch.Tensor, torch.Tensor]:
    """Return (heatmap focal loss, box L1 loss) of a raw output batch against its targets."""
    logits = out[:, 0]
    prob = torch.sigmoid(logits).clamp(1e-4, 1 - 1e-4)
    positive = heat.eq(1.0).float()
    pos = -torch.log(prob) * (1 - prob) ** 2 * positive
    neg = -torch.log(1 - prob) * prob ** 2 * (1 - heat) ** 4 * (1 - positive)
    count = positive.sum().clamp(min=1.0)
    focal = (pos.sum() + neg.sum()) / count
    has = index >= 0
    if not bool(has.any()):
        return focal, out.sum() * 0.0
    flat = out[has, 1:5].flatten(2)  # (b, 4, H*W)
    picked = flat.gather(2, index[has].view(-1, 1, 1).expand(-1, 4, 1)).squeeze(2)
    box = functional.l1_loss(picked, regress[has], reduction='sum') / count
    return focal, box


def load_exported(net: BallNet, path: str, images: torch.Tensor) -> None:
    """Load into ``net`` the weights of its ``model.onnx`` export, to train it further.

    The export folds each batch norm into its convolution; each one is set back so that the
    network computes what the ONNX model computes (exactly in eval mode): its statistics
    measured on ``images`` (a batch, as the network takes them) and a scale and shift that
    undo them.
    Raises ``ValueError`` when the file is not an export of this network.
    """
    import onnx
    from onnx import numpy_helper

    graph = onnx.load(path).graph
    weights = {t.name: numpy_helper.to_array(t) for t in graph.initializer}
    nodes = [node for node in graph.node if node.op_type == 'Conv']
    order: list[nn.Conv2d] = []  # the convolutions in the order they run, as exported
    hooks = [m.register_forward_hook(lambda m, i, o: order.append(m))
             for m in net.modules() if isinstance(m, nn.Conv2d)]
    net.eval()
    with torch.no_grad():
        net(images[:1])
    for hook in hooks:
        hook.remove()
    norms = {a: b for m in net.modules() if isinstance(m, nn.Sequential)
             for a, b in zip(m, list(m)[1:]) if isinstance(b, nn.BatchNorm2d)}
    if len(order) != len(nodes):
        raise ValueError(f'{path}: {len(nodes)} convolutions, the network has {len(order)}')
    with torch.no_grad():
        for conv, node in zip(order, nodes):
            weight = torch.from_numpy(weights[node.input[1]].copy())
            bias = torch.from_numpy(weights[node.input[2]].copy())
            if weight.shape != conv.weight.shape:
                raise ValueError(f'{path}: a {tuple(weight.shape)} convolution where the '
                                 f'network has {tuple(conv.weight.shape)}')
            conv.weight.copy_(weight)
            norm = norms.get(conv)
            if norm is None:
                conv.bias.copy_(bias)
                continue
            norm.weight.fill_(1.0)
            norm.bias.copy_(bias)
            norm.running_mean.zero_()
            norm.running_var.fill_(1.0 - norm.eps)
        stats = {}
        hooks = [norm.register_forward_hook(lambda m, i, o: stats.__setitem__(
            m, (i[0].mean((0, 2, 3)), i[0].var((0, 2, 3), unbiased=False))))
            for norm in norms.values()]
        net(images)
        for hook in hooks:
            hook.remove()
        for norm, (mean, var) in stats.items():
            norm.running_mean.copy_(mean)
            norm.running_var.copy_(var)
            norm.weight.copy_(torch.sqrt(var + norm.eps))
            norm.bias.add_(mean)
