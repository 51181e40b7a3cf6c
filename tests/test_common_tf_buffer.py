"""The transform buffer's lookups, and their bounded wait for frames still to come."""

import math
import threading
import time

from geometry_msgs.msg import TransformStamped
import numpy as np
import pytest
from rclpy.serialization import serialize_message
from tf2_msgs.msg import TFMessage
from ur_rg2_common.tf_buffer import FrameLookupError, TransformBuffer


def _shifted(x: float) -> np.ndarray:
    pose = np.eye(4)
    pose[0, 3] = x
    return pose


def test_lookup_chains_the_transforms():
    tree = TransformBuffer()
    tree.set_transform('world', 'base_link', _shifted(1.0))
    tree.set_transform('base_link', 'tool0', _shifted(0.5))
    assert tree.lookup('world', 'tool0')[0, 3] == pytest.approx(1.5)
    assert tree.lookup('tool0', 'world')[0, 3] == pytest.approx(-1.5)


def test_an_unknown_frame_is_refused_at_once_without_a_timeout():
    tree = TransformBuffer()
    tree.set_transform('world', 'base_link', _shifted(1.0))
    with pytest.raises(FrameLookupError, match="unknown frame 'camera_link'"):
        tree.lookup('world', 'camera_link')


def test_a_lookup_with_a_timeout_waits_for_the_frame_to_arrive():
    tree = TransformBuffer()
    tree.set_transform('world', 'base_link', _shifted(1.0))
    asked = threading.Event()

    def publish_later() -> None:
        asked.wait(10.0)
        tree.set_transform('world', 'camera_link', _shifted(3.0))

    publisher = threading.Thread(target=publish_later)
    publisher.start()
    try:
        asked.set()
        pose = tree.lookup('base_link', 'camera_link', timeout=30.0)
    finally:
        publisher.join(10.0)
    assert pose[0, 3] == pytest.approx(2.0)


def test_a_lookup_with_a_timeout_gives_up_with_the_reason():
    tree = TransformBuffer()
    tree.set_transform('world', 'base_link', _shifted(1.0))
    tree.set_transform('map', 'camera_link', _shifted(1.0))
    started = time.monotonic()
    with pytest.raises(FrameLookupError, match='not connected'):
        tree.lookup('base_link', 'camera_link', timeout=0.2)
    assert time.monotonic() - started >= 0.2


def test_serialized_messages_give_the_transforms_their_fields_give():
    messages = []
    for n in range(1, 6):  # frame names of every length modulo the alignments
        message = TFMessage()
        for k in range(n):
            stamped = TransformStamped()
            stamped.header.stamp.sec, stamped.header.stamp.nanosec = 17 + k, 5 * k
            stamped.header.frame_id = 'p' * (k + n)
            stamped.child_frame_id = '/c' + 'x' * k
            t, r = stamped.transform.translation, stamped.transform.rotation
            t.x, t.y, t.z = 0.1 * k, -2.0, 1e-9 * n
            r.x, r.y, r.z, r.w = 0.0, math.sin(k / 2), 0.0, math.cos(k / 2)
            message.transforms.append(stamped)
        messages.append(message)
    messages.append(TFMessage())
    for message in messages:
        by_fields, by_bytes = TransformBuffer(), TransformBuffer()
        assert by_fields.add_message(message) == by_bytes.add_serialized(
            serialize_message(message))
        assert by_fields.frames() == by_bytes.frames()
        for stamped in message.transforms:
            parent, child = stamped.header.frame_id, stamped.child_frame_id
            assert by_bytes.lookup(parent, child) == pytest.approx(
                by_fields.lookup(parent, child))
    assert TransformBuffer().add_serialized(b'\x00\x07\x00\x00') == 1  # not plain CDR
    assert TransformBuffer().add_serialized(serialize_message(messages[2])[:40]) == 1
