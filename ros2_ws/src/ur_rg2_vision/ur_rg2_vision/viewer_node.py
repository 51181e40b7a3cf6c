"""Node ``ur_rg2_viewer``: the camera, joint angles, gripper and ball, live in a web browser.

For headless users (SSH, containers): open the logged URL. The HTTP side lives in
:mod:`ur_rg2_vision.viewer_web`; this module only wires ROS topics into its hub.
"""

from __future__ import annotations

import ipaddress
import sys

from geometry_msgs.msg import PointStamped
from rcl_interfaces.msg import IntegerRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, JointState

from ur_rg2_vision.ros_image import image_to_rgb
from ur_rg2_vision.spin import run_node
from ur_rg2_vision.viewer_web import FrameHub, ViewerServer, finite_or_none, joint_summary

NODE_NAME = 'ur_rg2_viewer'


def _is_loopback(address: str) -> bool:
    try:
        return ipaddress.ip_address(address).is_loopback
    except ValueError:
        return address == 'localhost'


class ViewerNode(Node):
    """Serves the annotated camera stream and the robot's state over HTTP."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        address = self.declare_parameter('address', '127.0.0.1', ParameterDescriptor(
            description='Address to serve on. Loopback by default: the page has no '
                        'authentication, so only set another address on a trusted network.',
            read_only=True)).value
        port = self.declare_parameter('port', 8080, ParameterDescriptor(
            description='TCP port to serve on (0: any free port, logged at start-up).',
            read_only=True, integer_range=[IntegerRange(from_value=0, to_value=65535)])).value
        image_topic = self.declare_parameter('image_topic', 'ball/image', ParameterDescriptor(
            description='Colour image topic to stream: the annotated ball/image, or '
                        'camera/color/image_raw to watch the raw camera without vision.',
            read_only=True)).value
        quality = self.declare_parameter('jpeg_quality', 80, ParameterDescriptor(
            description='JPEG quality of the stream and snapshots, 1-100.', read_only=True,
            integer_range=[IntegerRange(from_value=1, to_value=100)])).value

        self._hub = FrameHub(quality)
        # Reliable: across processes best effort loses most 640x480 frames here. Depth 5 as
        # the sim and vision use: a busy moment (GIL, a loaded machine) must not drop frames;
        # the hub keeps only the newest anyway.
        self.create_subscription(Image, image_topic, self._on_image,
                                 QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE))
        self.create_subscription(JointState, 'joint_states', self._on_joint_state, 10)
        self.create_subscription(PointStamped, 'ball/position', self._on_ball, 10)

        # Last, so that nothing before it can fail (e.g. a signal mid-construction) and leave
        # the server thread running with no node to stop it.
        self._server = ViewerServer(self._hub, address, port)
        try:
            self._server.start()
        except OSError as error:
            self.destroy_node()
            raise OSError(f'cannot serve on {address} port {port}: {error}') from error

        if not _is_loopback(address):
            self.get_logger().warning(
                f'serving on non-loopback address {address}: anyone who can reach it sees '
                'the camera')
        self.get_logger().info(
            f'live view of {self.resolve_topic_name(image_topic)} at {self.url}')

    @property
    def url(self) -> str:
        """Address of the page."""
        return self._server.url

    def _on_image(self, msg: Image) -> None:
        try:
            self._hub.put_frame(image_to_rgb(msg))
        except ValueError as error:
            self.get_logger().warning(f'image dropped: {error}', throttle_duration_sec=10.0)

    def _on_joint_state(self, msg: JointState) -> None:
        if len(msg.position) != len(msg.name):
            return  # positions omitted or malformed: no angles to show from this message
        for key, value in joint_summary(msg.name, msg.position).items():
            self._hub.set_state(key, value)

    def _on_ball(self, msg: PointStamped) -> None:
        point = msg.point
        self._hub.set_state('ball', {'frame_id': msg.header.frame_id, 'x': finite_or_none(point.x),
                                     'y': finite_or_none(point.y), 'z': finite_or_none(point.z)})

    def destroy_node(self) -> None:
        """Stop the web server (ending every stream), then the node."""
        self._server.stop()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Run the viewer until Ctrl-C / SIGTERM; exit code 1 when the port cannot be bound."""
    return run_node(ViewerNode, args, 'ur_rg2_viewer', startup_errors=(OSError,))


if __name__ == '__main__':
    sys.exit(main())
