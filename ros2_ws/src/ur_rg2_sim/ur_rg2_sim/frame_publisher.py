"""Publishers of the sim's frames: /tf, /tf_static, robot_description and ball/true_pose.

The transforms come from :mod:`ur_rg2_sim.frames`; this module only fills messages. /tf and
ball/true_pose run at joint_state_rate on the simulation thread (thousands a second at
real-time factor 0), so they are published as bytes serialized once and rewritten with the
new numbers, and only while someone subscribes (:mod:`ur_rg2_sim.serialized`).
"""

from collections.abc import Sequence

from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped, TransformStamped
from rclpy.node import Node
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage
from ur_rg2_common.contract import LATCHED_QOS, TF_QOS, WORLD_FRAME

from ur_rg2_sim.frames import FrameTree, camera_transforms
from ur_rg2_sim.serialized import SerializedPublisher
from ur_rg2_sim.simulation import NS


class FramePublisher:
    """Publishes the transform tree, the robot description and the ball's true pose."""

    def __init__(self, node: Node, tree: FrameTree, description: str, prefix: str,
                 joint_names: Sequence[str]) -> None:
        self._tree = tree
        self._prefix = prefix
        self._static_pub = node.create_publisher(TFMessage, '/tf_static', LATCHED_QOS)
        description_pub = node.create_publisher(String, 'robot_description', LATCHED_QOS)
        description_pub.publish(String(data=description))
        # joint_states order -> the tree's moving-joint order.
        self._order = [list(joint_names).index(name) for name in tree.moving_joint_names]
        frames = [(self._frame(parent), self._frame(child))
                  for parent, child, *_ in tree.transforms([0.0] * len(self._order))]
        self._tf = SerializedPublisher(
            node, TFMessage, '/tf', TF_QOS, lambda doubles, words: TFMessage(transforms=[
                _transform(parent, child, doubles[7 * i:7 * i + 3],
                           doubles[7 * i + 3:7 * i + 7],
                           Time(sec=int(words[2 * i]), nanosec=int(words[2 * i + 1])))
                for i, (parent, child) in enumerate(frames)]), 7 * len(frames), 2 * len(frames))
        self._pose = SerializedPublisher(
            node, PoseStamped, 'ball/true_pose', 10,
            lambda doubles, words: _pose(self._frame(WORLD_FRAME), doubles, words), 7, 2)

    def _frame(self, name: str) -> str:
        return self._prefix + name

    def publish_static(self, stamp: Time, camera_position: Sequence[float],
                       camera_look_at: Sequence[float]) -> None:
        """Publish every fixed transform, the camera's from its current pose."""
        transforms = self._tree.static + camera_transforms(camera_position, camera_look_at)
        msg = TFMessage(transforms=[
            _transform(self._frame(parent), self._frame(child), translation, rotation, stamp)
            for parent, child, translation, rotation in transforms])
        self._static_pub.publish(msg)

    @property
    def subscribed(self) -> bool:
        """Whether anyone subscribes to /tf or ball/true_pose (else :meth:`publish` is idle)."""
        return bool(self._tf.subscribers or self._pose.subscribers)

    def publish(self, stamp_ns: int, positions: Sequence[float],
                ball_pose: tuple[Sequence[float], Sequence[float]]) -> None:
        """Publish /tf for joint ``positions`` (joint_states order) and the ball's pose."""
        stamp_words = divmod(stamp_ns, NS)
        if self._tf.subscribers:
            moving = self._tree.transforms([positions[i] for i in self._order])
            self._tf.publish([v for _, _, translation, rotation in moving
                              for v in (*translation, *rotation)], stamp_words * len(moving))
        self._pose.publish((*ball_pose[0], *ball_pose[1]), stamp_words)


def _pose(frame: str, doubles, words) -> PoseStamped:
    message = PoseStamped()
    message.header.frame_id = frame
    message.header.stamp = Time(sec=int(words[0]), nanosec=int(words[1]))
    p, q = message.pose.position, message.pose.orientation
    p.x, p.y, p.z = (float(v) for v in doubles[:3])
    q.x, q.y, q.z, q.w = (float(v) for v in doubles[3:7])
    return message


def _transform(parent: str, child: str, translation, rotation,
               stamp: Time | None = None) -> TransformStamped:
    message = TransformStamped(child_frame_id=child)
    message.header.frame_id = parent
    if stamp is not None:
        message.header.stamp = stamp
    t, r = message.transform.translation, message.transform.rotation
    t.x, t.y, t.z = (float(v) for v in translation)
    r.x, r.y, r.z, r.w = (float(v) for v in rotation)
    return message

