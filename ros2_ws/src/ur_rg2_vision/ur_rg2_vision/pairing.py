"""Colour frames paired with their depth images by stamp, whichever comes first. No ROS."""

from collections import OrderedDict
from typing import Generic, TypeVar

import numpy as np

Frame = TypeVar('Frame')
Key = tuple[int, int]  # a header stamp: (sec, nanosec)


class FramePairs(Generic[Frame]):
    """Colour frames waiting for their depth, and depth images that came before their frame.

    Both queues are bounded: the oldest entries go first (a late frame is worth less than the
    next one).
    """

    def __init__(self, pending: int, early: int) -> None:
        self._pending: OrderedDict[Key, Frame] = OrderedDict()
        self._early: OrderedDict[Key, np.ndarray] = OrderedDict()
        self._max_pending = pending
        self._max_early = early

    def add_color(self, key: Key, frame: Frame) -> tuple[np.ndarray | None, list[Frame]]:
        """Return (its depth if that came first, frames whose depth will never come now)."""
        depth = self._early.pop(key, None)
        if depth is not None:
            return depth, []
        self._pending[key] = frame
        stale = []
        while len(self._pending) > self._max_pending:
            stale.append(self._pending.popitem(last=False)[1])
        return None, stale

    def add_depth(self, key: Key, depth: np.ndarray) -> Frame | None:
        """Return the colour frame this depth completes, None if it has not come (kept)."""
        frame = self._pending.pop(key, None)
        if frame is None:
            self._early[key] = depth
            while len(self._early) > self._max_early:
                self._early.popitem(last=False)
        return frame
