"""Node ``ur_rg2_view3d``: the scene in 3D in a web browser, live or from a replay.

The robot's meshes at the current joint states (``robot_description``, ``joint_states``), the
RG2's opening, the ball where the physics has it (``ball/true_pose``) and where vision found it
(``ball/position``), the camera's frustum (``camera/color/camera_info`` and the tree) with the
point cloud of its depth image, and the last pick's target (``pick_ball/result``). The HTTP side
lives in :mod:`ur_rg2_tools.view3d_web`; this module wires topics into its :class:`Scene`.
The busy topics (joint states, ``/tf``, the ball, camera_info and images) wait in an
:class:`~ur_rg2_common.inbox.Inbox` until a page asks for the scene; images are taken serialized
and decoded only when a page asks for the point cloud.
"""

from __future__ import annotations

import re
import sys
import threading

from geometry_msgs.msg import PointStamped, PoseStamped
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import CameraInfo, Image, JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage
from ur_rg2_common.contract import GRIPPER_JOINTS, LATCHED_QOS, TF_QOS, WORLD_FRAME
from ur_rg2_common.inbox import Arrival, Inbox
from ur_rg2_common.parameters import declare_parameters, follow_settings
from ur_rg2_common.spin import run_node
from ur_rg2_common.tf_buffer import FrameLookupError, TransformBuffer, transform_point
from ur_rg2_vision.ros_image import image_to_depth, image_to_rgb
from ur_rg2_vision.viewer_web import is_loopback

from ur_rg2_tools.settings import VIEW3D_PARAMETERS, View3dSettings
from ur_rg2_tools.view3d_web import Scene, View3dServer, depth_cloud, finite

NODE_NAME = 'ur_rg2_view3d'
# pick_ball/result's text names the ball it went for: "... at (x, y, z) m in base_link ...".
_PICK_TARGET = re.compile(r'at \(([-\d.]+), ([-\d.]+), ([-\d.]+)\) m in (\w+)')


class View3dNode(Node):
    """Serves the 3D view of the robot, ball, camera and point cloud over HTTP."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.settings = s = View3dSettings.from_values(
            declare_parameters(self, VIEW3D_PARAMETERS))
        follow_settings(self, VIEW3D_PARAMETERS, View3dSettings.from_values,
                        lambda settings: setattr(self, 'settings', settings))
        self.scene = Scene()
        self.scene.cloud = self._cloud
        self.scene.refresh = self._refresh
        self._tree = TransformBuffer()
        self._images: dict[str, bytes] = {}  # latest serialized depth and colour images
        self._info: CameraInfo | None = None
        self._root = WORLD_FRAME
        self._pick: tuple | None = None
        # One page's /scene or /cloud at a time through the inboxes, the tree and the pick.
        self._refreshing = threading.Lock()
        # Only the newest image matters: DDS keeps one of each.
        images = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
        # /tf first: the ball's and the camera's poses are looked up in the tree.
        self._inboxes = [
            Inbox(self, TFMessage, '/tf', TF_QOS, lambda data, _: self._tree.add_serialized(data),
                  raw=True),
            Inbox(self, CameraInfo, 'camera/color/camera_info', 1, self._on_info),
            Inbox(self, JointState, 'joint_states', 100, self._on_joints),
            Inbox(self, PoseStamped, 'ball/true_pose', 1, self._on_true_pose),
            Inbox(self, PointStamped, 'ball/position', 1, self._on_ball),
            *(Inbox(self, Image, topic, images, lambda data, _, key=key:
                    self._images.__setitem__(key, data), raw=True)
              for key, topic in (('depth', 'camera/depth/image_raw'),
                                 ('color', 'camera/color/image_raw'))),
        ]
        self.create_subscription(String, 'robot_description', self._on_description,
                                 LATCHED_QOS)
        self.create_subscription(TFMessage, '/tf_static', self._tree.add_message, LATCHED_QOS)
        self.create_subscription(String, 'pick_ball/result', self._on_pick, LATCHED_QOS)

        self._server = View3dServer(self.scene, s.address, s.port)
        try:
            self._server.start()
        except OSError as error:
            self.destroy_node()
            raise OSError(f'cannot serve on {s.address} port {s.port}: {error}') from error
        if not is_loopback(s.address):
            self.get_logger().warning(f'serving on non-loopback address {s.address}: '
                                      'anyone who can reach it sees the scene')
        self.get_logger().info(f'3D view at {self.url}')

    @property
    def url(self) -> str:
        """Address of the page."""
        return self._server.url

    def _world(self, frame: str, point) -> list[float] | None:
        try:
            return finite(transform_point(self._tree.lookup(WORLD_FRAME, frame), point))
        except FrameLookupError:
            return None

    def _on_joints(self, msg: JointState, arrival: Arrival) -> None:
        if len(msg.position) != len(msg.name):
            return
        joints = {name: value for name, value in zip(msg.name, msg.position, strict=True)}
        self.scene.set('joints', {name: round(value, 5) for name, value in joints.items()},
                       arrival.received)
        fingers = [joints.get(name) for name in GRIPPER_JOINTS]
        # Each RG2 finger joint is half the opening between the pads (m).
        self.scene.set('gripper_opening_mm', round(1000 * sum(fingers), 1)
                       if None not in fingers else None, arrival.received)

    def _on_description(self, msg: String) -> None:
        try:
            meshes = self.scene.set_description(msg.data)
        except ValueError as error:
            self.get_logger().warning(f'robot_description ignored: {error}')
            return
        children = set(re.findall(r'<child\s+link="([^"]+)"', msg.data))
        roots = [name for name in re.findall(r'<link\s+name="([^"]+)"', msg.data)
                 if name not in children]
        self._root = roots[0] if roots else WORLD_FRAME
        self.get_logger().info(f'robot_description: {meshes} mesh files, root {self._root}')

    def _on_info(self, msg: CameraInfo, _arrival: Arrival) -> None:
        self._info = msg

    def _on_true_pose(self, msg: PoseStamped, arrival: Arrival) -> None:
        p = msg.pose.position
        self.scene.set('ball_true', self._world(msg.header.frame_id, (p.x, p.y, p.z)),
                       arrival.received)

    def _on_ball(self, msg: PointStamped, arrival: Arrival) -> None:
        p = msg.point
        self.scene.set('ball_detected', self._world(msg.header.frame_id, (p.x, p.y, p.z)),
                       arrival.received)

    def _on_pick(self, msg: String) -> None:
        match = _PICK_TARGET.search(msg.data)
        with self._refreshing:  # not between _update_frames' reading and clearing it
            self._pick = (msg.data, match)
            self.scene.set('pick', {'text': msg.data, 'target': None})

    def _pull(self) -> None:
        """Take what came on the busy topics (web threads, holding ``_refreshing``)."""
        for inbox in self._inboxes:
            inbox.pull()

    def _refresh(self) -> None:
        """Bring the scene up to date before a page reads it (web thread)."""
        with self._refreshing:
            self._pull()
            self._update_frames()

    def _update_frames(self) -> None:
        info = self._info
        if info is not None:
            try:
                pose = self._tree.lookup(WORLD_FRAME, info.header.frame_id)
                self.scene.set('camera', {
                    'pose': finite(pose.T.ravel()), 'k': finite(info.k),
                    'width': info.width, 'height': info.height})
            except FrameLookupError:
                pass
        try:
            self.scene.set('root', finite(self._tree.lookup(WORLD_FRAME, self._root).T.ravel()))
        except FrameLookupError:
            pass
        if self._pick is not None:
            text, match = self._pick
            target = (self._world(match.group(4), [float(v) for v in match.group(1, 2, 3)])
                      if match else None)
            self.scene.set('pick', {'text': text, 'target': target})
            if target is not None or match is None:
                self._pick = None

    def _cloud(self) -> dict | None:
        """Return the latest depth image's points in the world (web thread), or None."""
        with self._refreshing:
            self._pull()
        depth, color, info = self._images.get('depth'), self._images.get('color'), self._info
        if depth is None or info is None:
            return None
        try:
            depth_msg = deserialize_message(depth, Image)
            pose = self._tree.lookup(WORLD_FRAME, depth_msg.header.frame_id or
                                     info.header.frame_id)
            rgb = image_to_rgb(deserialize_message(color, Image)) if color else None
            return depth_cloud(image_to_depth(depth_msg), info.k, pose,
                               self.settings.cloud_step, rgb)
        except (FrameLookupError, ValueError) as error:
            self.get_logger().warning(f'no point cloud: {error}', throttle_duration_sec=10.0)
            return None

    def destroy_node(self) -> None:
        """Stop the web server, then the node."""
        self._server.stop()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Run the 3D view until Ctrl-C / SIGTERM; exit code 1 on a bad parameter or a busy port."""
    return run_node(View3dNode, args, NODE_NAME,
                    startup_errors=(OSError, ValueError, ParameterException))


if __name__ == '__main__':
    sys.exit(main())
