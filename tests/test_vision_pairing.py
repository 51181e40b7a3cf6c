"""Colour frames paired with their depth by stamp, in either order, with bounded queues."""

import numpy as np
from ur_rg2_vision.pairing import FramePairs


def test_depth_after_its_colour_completes_the_frame():
    pairs = FramePairs(pending=2, early=2)
    assert pairs.add_color((1, 0), 'a') == (None, [])
    depth = np.ones((2, 2))
    assert pairs.add_depth((1, 0), depth) == 'a'
    assert pairs.add_depth((1, 0), depth) is None  # taken once


def test_depth_before_its_colour_is_kept_until_the_colour_comes():
    pairs = FramePairs(pending=2, early=2)
    depth = np.zeros((2, 2))
    assert pairs.add_depth((5, 1), depth) is None
    found, stale = pairs.add_color((5, 1), 'b')
    assert found is depth and stale == []


def test_the_oldest_entries_go_first_when_the_queues_are_full():
    pairs = FramePairs(pending=2, early=1)
    assert pairs.add_color((1, 0), 'a')[1] == []
    assert pairs.add_color((2, 0), 'b')[1] == []
    assert pairs.add_color((3, 0), 'c')[1] == ['a']  # its depth will never be used now
    assert pairs.add_depth((1, 0), np.zeros(1)) is None  # 'a' is gone: kept as early
    pairs.add_depth((9, 0), np.zeros(1))  # pushes out the depth of (1, 0)
    assert pairs.add_color((1, 0), 'a again')[0] is None
