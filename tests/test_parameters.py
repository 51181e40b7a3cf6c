"""Numbers as people type them: integers for double parameters, in every node (issue 13.4)."""

import os
from pathlib import Path
import select
import signal
import subprocess
import sys
import time

from conftest import wait_for
import pytest
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import DescribeParameters, GetParameters, SetParameters
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter
from ur_rg2_common.parameters import ParameterSpec, as_declared_type, declare_parameters
from ur_rg2_vision.viewer_node import ViewerNode

BIN = Path(sys.executable).parent
TIMEOUT = 60.0  # start-up of a node process (the sim loads pybullet) on a loaded machine


@pytest.mark.parametrize('declared, value, expected', [
    (Parameter.Type.DOUBLE, 15, 15.0),
    (Parameter.Type.DOUBLE, 0, 0.0),
    (Parameter.Type.DOUBLE_ARRAY, [1, 2, 0], [1.0, 2.0, 0.0]),
])
def test_integers_become_doubles(declared, value, expected):
    converted = as_declared_type(declared, value)
    assert converted == expected
    assert Parameter.Type.from_parameter_value(converted) is declared


@pytest.mark.parametrize('declared, value', [
    (Parameter.Type.DOUBLE, 'fast'),
    (Parameter.Type.DOUBLE, True),  # a bool is an int to Python, not a number to ROS
    (Parameter.Type.DOUBLE_ARRAY, ['a', 'b']),
    (Parameter.Type.INTEGER, 15),
    (Parameter.Type.INTEGER_ARRAY, [1, 2]),
    (Parameter.Type.STRING, 15),
])
def test_everything_else_is_left_for_rclpy_to_judge(declared, value):
    assert as_declared_type(declared, value) is value


SPECS = (
    ParameterSpec('rate', 30.0, 'a rate, Hz', bounds=(0.0, 100.0)),
    ParameterSpec('position', [0.5, 0.5, 0.0], 'a point, m'),
    ParameterSpec('count', 3, 'a count', bounds=(0, 10)),
    ('name', 'ball', 'a plain row', True),
)


def declare(graph, **overrides) -> Node:
    node = graph.node('declaring', parameter_overrides=[
        Parameter(name, value=value) for name, value in overrides.items()])
    declare_parameters(node, SPECS)
    return node


def test_integer_overrides_are_declared_as_doubles_with_their_descriptors(ros_graph):
    node = declare(ros_graph, rate=15, position=[1, 2, 0], count=4)
    assert node.get_parameter('rate').get_parameter_value().double_value == 15.0
    assert node.get_parameter('position').type_ is Parameter.Type.DOUBLE_ARRAY
    assert list(node.get_parameter('position').value) == [1.0, 2.0, 0.0]
    assert node.get_parameter('count').value == 4
    rate = node.describe_parameter('rate')
    assert (rate.type, rate.description) == (ParameterType.PARAMETER_DOUBLE, 'a rate, Hz')
    assert rate.floating_point_range[0].to_value == 100.0 and not rate.dynamic_typing
    assert node.describe_parameter('count').integer_range[0].to_value == 10
    assert node.describe_parameter('name').read_only


@pytest.mark.parametrize('overrides, error', [
    ({'rate': 'fast'}, InvalidParameterTypeException),
    ({'count': 2.5}, InvalidParameterTypeException),
    ({'rate': 150}, InvalidParameterValueException),  # converted, then out of range
])
def test_wrong_start_up_values_are_still_refused(ros_graph, overrides, error):
    with pytest.raises(error):
        declare(ros_graph, **overrides)


def test_run_time_integers_become_doubles_and_wrong_kinds_are_refused(ros_graph):
    node = declare(ros_graph)
    assert node.set_parameters([Parameter('rate', value=20)])[0].successful
    assert node.get_parameter('rate').type_ is Parameter.Type.DOUBLE
    (result,) = node.set_parameters([Parameter('rate', value='fast')])
    assert not result.successful and 'type' in result.reason
    (result,) = node.set_parameters([Parameter('count', value=2.0)])
    assert not result.successful and 'type' in result.reason
    assert node.get_parameter('rate').value == 20.0


# -- every node, as a process started the way users start it ---------------------------------

class NodeProcess:
    """A node executable on a pseudo-terminal (keys needs one), and its parameter services."""

    def __init__(self, graph, executable: str, node_name: str, parameters: list[str]) -> None:
        master, slave = os.openpty()
        self._master = master
        args = [str(BIN / executable), '--ros-args']
        for parameter in parameters:
            args += ['-p', parameter]
        self.process = subprocess.Popen(args, stdin=slave, stdout=slave, stderr=slave,
                                        env=graph.env, start_new_session=True)
        os.close(slave)
        self.output = b''
        client = graph.node(f'{node_name}_parameters')
        self._clients = {kind: client.create_client(kind, f'{node_name}/{service}')
                         for kind, service in ((GetParameters, 'get_parameters'),
                                               (SetParameters, 'set_parameters'),
                                               (DescribeParameters, 'describe_parameters'))}

    def _call(self, kind, request):
        client = self._clients[kind]
        wait_for(lambda: client.service_is_ready() or self._exited(), TIMEOUT,
                 f'{client.srv_name} (output so far: {self.output!r})')
        assert self.process.poll() is None, f'exited: {self.output.decode()}'
        future = client.call_async(request)
        wait_for(future.done, 10.0, f'an answer from {client.srv_name}')
        return future.result()

    def _exited(self) -> bool:
        self._drain()
        return self.process.poll() is not None

    def _drain(self) -> None:
        try:
            while select.select([self._master], [], [], 0)[0]:
                chunk = os.read(self._master, 65536)
                if not chunk:
                    return
                self.output += chunk
        except OSError:  # the terminal's other side is gone: the process has exited
            pass

    def get(self, name: str) -> Parameter:
        value = self._call(GetParameters, GetParameters.Request(names=[name])).values[0]
        return Parameter.from_parameter_msg(ParameterMsg(name=name, value=value))

    def set(self, name: str, value):
        message = Parameter(name, value=value).to_parameter_msg()
        return self._call(SetParameters, SetParameters.Request(parameters=[message])).results[0]

    def describe(self, name: str):
        request = DescribeParameters.Request(names=[name])
        return self._call(DescribeParameters, request).descriptors[0]

    def stop(self) -> tuple[int, str]:
        """Send SIGINT; return the exit code and everything the node wrote."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        deadline = time.monotonic() + 15.0
        while not self._exited():
            if time.monotonic() > deadline:
                self.process.kill()
                raise AssertionError(f'still running 15 s after SIGINT: {self.output!r}')
            time.sleep(0.05)
        self._drain()
        os.close(self._master)
        return self.process.returncode, self.output.decode(errors='replace')


# executable, node name, start-up parameters as typed, the doubles they give,
# a run-time integer for a double parameter, a double parameter for a wrong-kind value
NODES = [
    pytest.param(
        'sim', 'ur_rg2_sim',
        ['camera_rate:=15', 'real_time_factor:=0', 'ball_position:=[1,2,0]',
         'physics_rate:=240', 'camera_width:=64', 'camera_height:=48'],
        {'camera_rate': 15.0, 'real_time_factor': 0.0, 'ball_position': [1.0, 2.0, 0.0],
         'physics_rate': 240.0},  # the last one read-only
        ('real_time_factor', 1), 'camera_rate', id='sim'),
    pytest.param(
        'vision', 'ur_rg2_vision', ['ball_radius:=1', 'min_radius_px:=5'],
        {'ball_radius': 1.0, 'min_radius_px': 5.0}, ('min_radius_px', 6), 'ball_radius',
        id='vision'),
    pytest.param(
        'keys', 'ur_rg2_teleop', ['step_deg:=2'], {'step_deg': 2.0}, ('step_deg', 3),
        'step_deg', id='keys'),
]


@pytest.mark.parametrize('executable, node_name, typed, doubles, run_time, wrong', NODES)
def test_node_takes_integers_for_doubles(ros_graph, tmp_path, executable, node_name, typed,
                                         doubles, run_time, wrong):
    if executable == 'vision':
        typed = [*typed, f'frames_dir:={tmp_path}']
    node = NodeProcess(ros_graph, executable, node_name, typed)
    try:
        for name, expected in doubles.items():
            parameter = node.get(name)
            assert parameter.type_ in (Parameter.Type.DOUBLE, Parameter.Type.DOUBLE_ARRAY), name
            assert parameter.value == pytest.approx(expected), name
            assert node.describe(name).type == parameter.type_.value
        name, integer = run_time
        result = node.set(name, integer)
        assert result.successful, result.reason
        assert node.get(name).get_parameter_value().double_value == float(integer)
        result = node.set(wrong, 'fast')
        assert not result.successful
        assert "expected 'Type.DOUBLE' got 'Type.STRING'" in result.reason
        assert node.get(wrong).type_ is Parameter.Type.DOUBLE
    finally:
        code, output = node.stop()
    assert code == 0, output
    assert 'Traceback' not in output


def test_viewer_parameters_keep_their_descriptors(ros_graph):
    """The viewer has no double parameter; its integers keep their ranges and stay read-only."""
    viewer = ros_graph.add(ViewerNode(context=ros_graph.context, parameter_overrides=[
        Parameter('port', value=0)]))
    port = viewer.describe_parameter('port')
    assert port.type == ParameterType.PARAMETER_INTEGER and port.read_only
    assert (port.integer_range[0].from_value, port.integer_range[0].to_value) == (0, 65535)
    (result,) = viewer.set_parameters([Parameter('jpeg_quality', value=50)])
    assert not result.successful and 'read-only' in result.reason
