"""Messages rewritten in their serialized bytes read back as the messages built the usual way.

Their publisher sends them to matched subscriptions only.
"""

from array import array

from builtin_interfaces.msg import Time
from conftest import wait_for
from geometry_msgs.msg import TransformStamped
import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage
from ur_rg2_sim.serialized import SerializedMessage, SerializedPublisher

FRAMES = [('world', 'base_link'), ('base_link', 'shoulder_link'), ('tool0', 'rg2_left_finger')]
NAMES = ['shoulder_pan_joint', 'elbow_joint', 'rg2_finger_joint']


def tf_message(doubles, words) -> TFMessage:
    transforms = []
    for i, (parent, child) in enumerate(FRAMES):
        message = TransformStamped(child_frame_id=child)
        message.header.frame_id = parent
        message.header.stamp = Time(sec=int(words[2 * i]), nanosec=int(words[2 * i + 1]))
        t, r = message.transform.translation, message.transform.rotation
        t.x, t.y, t.z, r.x, r.y, r.z, r.w = (float(v) for v in doubles[7 * i:7 * i + 7])
        transforms.append(message)
    return TFMessage(transforms=transforms)


def joint_state(doubles, words) -> JointState:
    n = len(NAMES)
    return JointState(header=Header(stamp=Time(sec=int(words[0]), nanosec=int(words[1])),
                                    frame_id='x'),
                      name=NAMES, position=array('d', doubles[:n]),
                      velocity=array('d', doubles[n:2 * n]), effort=array('d', doubles[2 * n:]))


@pytest.mark.parametrize('build, message_type, n_doubles, n_words', [
    (tf_message, TFMessage, 7 * len(FRAMES), 2 * len(FRAMES)),
    (joint_state, JointState, 3 * len(NAMES), 2),
])
def test_filled_bytes_are_the_message_with_those_values(build, message_type, n_doubles,
                                                        n_words):
    serialized = SerializedMessage(build, n_doubles, n_words)
    rng = np.random.default_rng(7)
    for _ in range(20):
        doubles = rng.normal(size=n_doubles) * 10.0 ** rng.integers(-6, 6, size=n_doubles)
        doubles[0] = 0.0
        words = rng.integers(0, 2**31 - 1, size=n_words)
        filled = deserialize_message(serialized.fill(doubles, words), message_type)
        assert filled == build(doubles, words)


def test_a_value_that_is_not_in_its_own_field_is_refused():
    with pytest.raises(ValueError, match=r'found 21 times'):
        SerializedMessage(lambda doubles, words: tf_message(np.repeat(doubles[:1], 21), words),
                          7 * len(FRAMES), 2 * len(FRAMES))


def test_a_stream_goes_to_its_subscribers_from_their_match_on(ros_graph):
    stream = SerializedPublisher(ros_graph.node('streams'), JointState, 'states', 10,
                                 joint_state, 3 * len(NAMES), 2)
    assert stream.subscribers == 0
    stream.publish(np.ones(3 * len(NAMES)), (1, 2))  # to no one: not sent
    listener = ros_graph.node('listener')
    received = []
    subscription = listener.create_subscription(JointState, 'states', received.append, 10)
    wait_for(lambda: stream.subscribers == 1, 30, 'the publisher to hear of the match')
    doubles = np.arange(3.0 * len(NAMES))
    stream.publish(doubles, (3, 4))
    assert wait_for(lambda: received, 30, 'the message') == [joint_state(doubles, (3, 4))]
    listener.destroy_subscription(subscription)
    wait_for(lambda: stream.subscribers == 0, 30, 'the publisher to hear of the unmatch')
