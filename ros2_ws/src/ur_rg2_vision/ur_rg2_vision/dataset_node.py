"""Executable ``dataset``: drive a running sim to write a labelled YOLO data set of the ball.

This module holds the ROS side (the sim's parameters, its topics, the waits) and ``main``; the
options, the sampler and the loop are in :mod:`ur_rg2_vision.dataset_run`, the placements in
:mod:`ur_rg2_vision.placement`, the labels and the files in :mod:`ur_rg2_vision.dataset`.
"""

from __future__ import annotations

from collections.abc import Sequence
import signal
import sys

from geometry_msgs.msg import PoseStamped
from rcl_interfaces.srv import GetParameters, SetParametersAtomically
import rclpy
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args
from sensor_msgs.msg import CameraInfo, Image
from tf2_msgs.msg import TFMessage
from ur_rg2_common.contract import IMAGE_QOS, LATCHED_QOS
from ur_rg2_common.self_spinning import SelfSpinningNode

from ur_rg2_vision.dataset_run import InterruptError, SimError, SimRecord, parse_args, run


class SimDriver(SelfSpinningNode, SimRecord):
    """Sets the sim's parameters and collects what it publishes; waits by spinning itself."""

    error = SimError

    def __init__(self, sim_node: str, timeout: float) -> None:
        SelfSpinningNode.__init__(self, 'ur_rg2_dataset', timeout)
        SimRecord.__init__(self, timeout)
        self._sim = sim_node
        self._get = self.create_client(GetParameters, f'{sim_node}/get_parameters')
        # Atomically: the sim then takes a sample's changes in one go (one new camera for a
        # new pose, floor and light, not one per parameter).
        self._set = self.create_client(SetParametersAtomically,
                                       f'{sim_node}/set_parameters_atomically')
        for kind, topic, queue, qos in (
                (Image, 'camera/color/image_raw', self.colors, IMAGE_QOS),
                (CameraInfo, 'camera/color/camera_info', self.infos, IMAGE_QOS),
                (Image, 'camera/depth/image_raw', self.depths, IMAGE_QOS),
                (PoseStamped, 'ball/true_pose', self.poses, 50)):
            # Not queue.append itself: rclpy inspects the callback's signature.
            self.create_subscription(kind, topic, lambda msg, q=queue: q.append(msg), qos)
        self.create_subscription(TFMessage, '/tf_static', self._on_static, LATCHED_QOS)

    def _on_static(self, msg: TFMessage) -> None:
        for t in msg.transforms:
            self.add_static(t)

    def check_stop(self) -> None:
        """Raise InterruptError once a stop signal has come."""
        if self.stop_signal is not None:
            raise InterruptError(self.stop_signal)

    def call(self, client, request, what: str):
        """Call one of the sim's services, once it answers; SimError if the call fails."""
        if not client.service_is_ready():
            self.spin_until(client.service_is_ready, f'the sim node {self._sim!r} to answer '
                            f'({client.srv_name}): is the sim running (sim, or ros2 run '
                            f'ur_rg2_sim sim), on this ROS_DOMAIN_ID and namespace?')
        return super().call(client, request, what)

    def get_parameters(self, names: Sequence[str]) -> dict[str, object]:
        """Return the sim's values of parameters ``names``."""
        return self.parameters_of(self._get, names)

    def set_parameters(self, values: dict[str, object]) -> None:
        """Set the sim's parameters; SimError with the sim's reason if one is refused."""
        request = SetParametersAtomically.Request(parameters=[
            Parameter(name, value=value).to_parameter_msg() for name, value in values.items()])
        response = self.call(self._set, request, 'the sim to set ' + ', '.join(values))
        if not response.result.successful:
            raise SimError(f'the sim refused {", ".join(values)}: {response.result.reason}')


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``dataset`` command; return its exit code."""
    argv = list(sys.argv if argv is None else argv)
    args = parse_args(remove_ros_args(argv)[1:])
    # Installed before rclpy starts, so that a signal during start-up ends the run cleanly too;
    # a signal only sets a flag, checked between waits: a sample being written is finished.
    pending: list[int] = []
    driver: SimDriver | None = None

    def on_signal(signum, _frame) -> None:
        pending.append(signum)
        if driver is not None:
            driver.stop_signal = signum

    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, on_signal)
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    driver = SimDriver(args.sim_node, args.timeout)
    if pending:
        driver.stop_signal = pending[-1]
    try:
        return run(args, driver)
    finally:
        driver.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
