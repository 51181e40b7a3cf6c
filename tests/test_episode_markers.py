"""Episode markers on ``episode`` (std_msgs/String): keys and the pick mark episodes.

``keys`` runs on a pseudo-terminal as in test_teleop_pty; the sim and the motion node run
in-process as in test_motion_node; a probe listens to ``episode`` as the recorder does.
"""

import threading
import time

from conftest import wait_for
from std_msgs.msg import String
from test_motion_node import TIMEOUT, Rig
from test_teleop_pty import BANNER, KeysTerminal
from ur_rg2_common.contract import EPISODE_QOS, EPISODE_TOPIC

BALL = (0.4, -0.3, 0.03)  # world, on the floor


class Markers:
    """What a node published on ``episode``."""

    def __init__(self, node) -> None:
        self._lock = threading.Lock()
        self._seen: list[str] = []
        node.create_subscription(String, EPISODE_TOPIC, self._on, EPISODE_QOS)

    def _on(self, message: String) -> None:
        with self._lock:
            self._seen.append(message.data)

    def __call__(self) -> list[str]:
        with self._lock:
            return list(self._seen)


def test_a_pick_is_an_episode_and_a_refused_pick_none(ros_graph):
    rig = Rig(ros_graph, ball_position=list(BALL))
    markers = Markers(rig.node)
    wait_for(lambda: rig.node.count_publishers(EPISODE_TOPIC), TIMEOUT, 'the markers publisher')
    rig.show_ball(*BALL)
    picked = rig.pick()
    assert picked.success, picked.message
    assert markers() == ['start', 'success']
    refused = rig.pick()  # the ball was seen more than ball_timeout ago: no episode
    assert not refused.success and markers() == ['start', 'success']
    rig.show_ball(0.3, 0.2, 0.03)  # where there is no ball: the pick drops the ball and misses
    missed = rig.pick()
    assert not missed.success, missed.message
    assert markers() == ['start', 'success', 'start', 'failure']


def test_keys_b_n_j_mark_a_person_s_episodes(ros_graph):
    markers = Markers(ros_graph.node('probe'))
    keys = KeysTerminal(ros_graph.env)
    try:
        keys.expect('begin an episode / end it: a success / a failure', timeout=30.0)  # h
        keys.expect(BANNER)
        deadline = time.monotonic() + TIMEOUT
        while not markers():  # a marker sent before discovery completes is lost
            keys.press('b')
            keys.expect('episode started')
            assert time.monotonic() < deadline, 'no marker from keys'
            time.sleep(0.2)
        keys.press('N')  # upper case as lower case
        keys.expect('episode ended: success')
        keys.press('bj')
        keys.expect('episode ended: failure')
        wait_for(lambda: markers()[-4:] == ['start', 'success', 'start', 'failure'], TIMEOUT,
                 'the four markers')
        assert set(markers()[:-4]) <= {'start'}
        keys.press('p')
        assert keys.wait() == 0
    finally:
        keys.close()
