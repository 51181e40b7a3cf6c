"""The keys node in-process against stub publishers and services (no terminal, no sim)."""

import io
import math
import threading

from conftest import wait_for
import pytest
from rclpy.exceptions import InvalidParameterValueException
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger
from ur_rg2_common.contract import ARM_JOINTS, LATCHED_QOS
from ur_rg2_teleop.display import Console
from ur_rg2_teleop.keys_node import KeysNode


class Keys:
    """A KeysNode in the test graph, its console output, and what it publishes on joint_jog."""

    def __init__(self, graph, namespace: str = '', **kwargs) -> None:
        self.output = io.StringIO()
        self.node = graph.add(KeysNode(Console(self.output), context=graph.context,
                                       namespace=namespace, **kwargs))
        self.jogs: list[JointState] = []
        listener = graph.node('jog_listener', namespace=namespace)
        listener.create_subscription(JointState, 'joint_jog', self.jogs.append, 100)
        wait_for(lambda: self.node.count_subscribers('joint_jog') > 0, 10.0, 'jog subscriber')

    def press(self, keys: str) -> None:
        """Hand ``keys`` to the node one by one, as the key loop does."""
        for key in keys:
            assert self.node.handle_key(key)

    def lines(self) -> list[str]:
        """Return what the node has shown so far, line by line."""
        return self.output.getvalue().splitlines()


def stub_service(graph, name: str, success: bool, message: str,
                 release: threading.Event | None = None):
    """Serve a Trigger ``name`` answering (success, message), once ``release`` is set."""
    def serve(request, response):
        if release is not None:
            assert release.wait(30.0), f'{name}: the test never let the answer go'
        response.success, response.message = success, message
        return response

    graph.node(f'stub_{name.replace("/", "_")}').create_service(Trigger, name, serve)


def test_jog_keys_publish_one_relative_move_per_key_in_radians(ros_graph):
    keys = Keys(ros_graph)
    keys.press('qWx')
    wait_for(lambda: len(keys.jogs) == 3, 10.0, 'three joint_jog messages')
    step = math.radians(5.0)
    assert [(list(m.name), list(m.position)) for m in keys.jogs] == [
        (['shoulder_pan_joint'], [pytest.approx(step)]),
        (['shoulder_pan_joint'], [pytest.approx(-step)]),
        (['elbow_joint'], [pytest.approx(-step)]),
    ]


def test_every_jog_key_moves_its_joint(ros_graph):
    keys = Keys(ros_graph)
    keys.press('qwaszxerdfcv')
    wait_for(lambda: len(keys.jogs) == 12, 10.0, 'twelve joint_jog messages')
    expected = [(name, sign) for name in ARM_JOINTS for sign in (1, -1)]
    assert [(m.name[0], math.copysign(1, m.position[0])) for m in keys.jogs] == expected


def test_step_keys_change_the_step_parameter_within_bounds(ros_graph):
    keys = Keys(ros_graph, parameter_overrides=[Parameter('step_deg', value=2.5)])
    keys.press('q+q')
    assert keys.node.get_parameter('step_deg').value == 5.0
    keys.press('-' * 10 + 'w' + '+' * 10 + 'w')
    wait_for(lambda: len(keys.jogs) == 4, 10.0, 'four joint_jog messages')
    assert [math.degrees(m.position[0]) for m in keys.jogs] == [
        pytest.approx(2.5), pytest.approx(5.0), pytest.approx(-0.5), pytest.approx(-45.0)]
    steps = [line for line in keys.lines() if line.startswith('step')]
    # Each press says the step; at a limit, that it is the limit.
    assert steps[:4] == ['step 5 deg', 'step 2 deg', 'step 1 deg', 'step 0.5 deg (the smallest)']
    assert steps[11:14] == ['step 1 deg', 'step 2 deg', 'step 5 deg']
    assert steps[-1] == 'step 45 deg (the largest)'


def test_out_of_range_step_is_refused_at_start(ros_graph):
    with pytest.raises(InvalidParameterValueException):
        KeysNode(Console(io.StringIO()), context=ros_graph.context,
                 parameter_overrides=[Parameter('step_deg', value=90.0)])


def test_unknown_key_says_so_on_one_line(ros_graph):
    keys = Keys(ros_graph)
    keys.press('o')
    keys.node.handle_key('\x1b[A')
    assert keys.lines() == ["'o' has no function (h: help)", 'Up has no function (h: help)']
    assert not keys.jogs


def test_quit_keys_end_the_loop(ros_graph):
    keys = Keys(ros_graph)
    assert not keys.node.handle_key('p')
    assert not keys.node.handle_key('P')
    assert not keys.node.handle_key('\x03')


def test_services_are_called_without_blocking_and_answer_on_one_line(ros_graph):
    keys = Keys(ros_graph)
    release = threading.Event()
    stub_service(ros_graph, 'reset', True, 'arm targets\nset to home', release)
    stub_service(ros_graph, 'gripper/close', True, 'closed: nothing grasped')
    stub_service(ros_graph, 'gripper/open', False, 'fingers blocked')
    for name in ('reset', 'gripper/close', 'gripper/open'):
        client = keys.node._trigger_clients[name]  # the node's own view decides availability
        wait_for(client.service_is_ready, 10.0, f'{name} discovered')
    keys.press('lty')  # returns while reset has not answered yet: no key waits for one
    assert not any(line.startswith('/reset') for line in keys.lines())
    release.set()
    wait_for(lambda: len(keys.lines()) == 3, 10.0, 'three service results')
    assert sorted(keys.lines()) == [
        '/gripper/close: done: closed: nothing grasped',
        '/gripper/open: FAILED: fingers blocked',
        '/reset: done: arm targets set to home',
    ]


def test_missing_service_is_reported_at_once_on_one_line(ros_graph):
    keys = Keys(ros_graph, namespace='robot2')
    keys.press(' t')
    assert keys.lines() == ['/robot2/vision/save_frame: service not available',
                            '/robot2/gripper/close: service not available']


def test_jog_without_listener_or_joint_states_says_why(ros_graph):
    keys = KeysNode(Console(out := io.StringIO()), context=ros_graph.context)
    ros_graph.add(keys)
    keys.handle_key('q')
    assert out.getvalue() == '/joint_jog: nobody listens (is the sim running?)\n'


def test_angles_are_shown_once_when_the_move_is_over(ros_graph):
    keys = Keys(ros_graph, namespace='ns')
    publisher = ros_graph.node('fake_sim', namespace='ns').create_publisher(
        JointState, 'joint_states', 10)
    wait_for(lambda: publisher.get_subscription_count() > 0, 10.0, 'joint_states subscriber')
    stop = threading.Event()
    state = {'pan': 0.0, 'speed': 0.0, 'published': 0}

    def publish():
        while not stop.wait(0.01):
            msg = JointState(name=[*ARM_JOINTS, 'rg2_finger_joint'])
            msg.position = [state['pan'], -1.0, 0.5, 0.0, 0.0, 0.0, 0.02]
            msg.velocity = [state['speed'], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
            publisher.publish(msg)
            state['published'] += 1

    thread = threading.Thread(target=publish)
    thread.start()
    try:
        # The pose is shown once at start-up, when the states first come in.
        wait_for(lambda: keys.lines(), 10.0, 'the start-up pose')
        assert keys.lines()[0].startswith('joint mode | pan   +0.0  lift  -57.3  elbow  +28.6')
        keys.press('q')
        state['speed'] = 1.0
        moving = state['published']
        wait_for(lambda: state['published'] >= moving + 10, 10.0, '0.1 s of moving states')
        state.update(pan=math.radians(5.0), speed=0.0)
        wait_for(lambda: len(keys.lines()) >= 2, 10.0, 'the angles after the move')
        # Shown while moving, the line would have the pan of then: +0.0.
        assert keys.lines()[1].startswith('joint mode | pan   +5.0  lift  -57.3')
        assert keys.lines()[1].endswith('(step 5)')
        # Three times the settle time of still states more: no second line for one move.
        still = state['published']
        wait_for(lambda: state['published'] >= still + 30, 10.0, '0.3 s of still states')
        assert len(keys.lines()) == 2, 'angles shown more than once per move'
    finally:
        stop.set()
        thread.join()


def test_policy_episode_outcomes_are_shown_on_one_line_each(ros_graph):
    policy = ros_graph.node('policy_stand_in')
    results = policy.create_publisher(String, 'policy/result', LATCHED_QOS)
    results.publish(String(data='success: an episode before keys started (1.0 s)'))
    keys = Keys(ros_graph)
    wait_for(lambda: results.get_subscription_count() > 0, 10.0, 'keys to subscribe')
    results.publish(String(data='success: picked the ball: held 12 cm above the floor after '
                                '40 steps (6.3 s)'))
    results.publish(String(data='failed: missed the ball:\nopen after 50 steps (7.9 s)'))
    wait_for(lambda: len(keys.lines()) == 2, 10.0, 'two outcome lines')
    assert keys.lines() == [
        'policy episode: done: picked the ball: held 12 cm above the floor after 40 steps '
        '(6.3 s)',
        'policy episode: FAILED: missed the ball: open after 50 steps (7.9 s)',
    ]
