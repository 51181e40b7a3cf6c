"""Publishers of the sim's frames: /tf, /tf_static, robot_description and ball/true_pose.

The transforms come from :mod:`ur_rg2_sim.frames`; this module only fills messages. /tf runs
at joint_state_rate on the simulation thread, so its message is built once and refilled in
place: a revolute joint changes only its rotation, a prismatic one only its translation.
"""

from collections.abc import Sequence

from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped, TransformStamped
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from ur_rg2_sim.frames import WORLD_FRAME, FrameTree, camera_transforms

# As tf2_ros's broadcasters and robot_state_publisher: late joiners get the latest message.
LATCHED_QOS = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL,
                         reliability=ReliabilityPolicy.RELIABLE)
TF_QOS = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                    reliability=ReliabilityPolicy.RELIABLE)


class FramePublisher:
    """Publishes the transform tree, the robot description and the ball's true pose."""

    def __init__(self, node: Node, tree: FrameTree, description: str, prefix: str,
                 joint_names: Sequence[str]) -> None:
        self._tree = tree
        self._prefix = prefix
        self._tf_pub = node.create_publisher(TFMessage, '/tf', TF_QOS)
        self._static_pub = node.create_publisher(TFMessage, '/tf_static', LATCHED_QOS)
        self._true_pose_pub = node.create_publisher(PoseStamped, 'ball/true_pose', 10)
        description_pub = node.create_publisher(String, 'robot_description', LATCHED_QOS)
        description_pub.publish(String(data=description))
        # joint_states order -> the tree's moving-joint order.
        self._order = [list(joint_names).index(name) for name in tree.moving_joint_names]
        self._moving = [_transform(self._frame(parent), self._frame(child), translation, rotation)
                        for parent, child, translation, rotation in tree.transforms(
                            [0.0] * len(self._order))]
        self._prismatic = [joint.kind == 'prismatic' for joint in tree.moving]
        self._tf_msg = TFMessage(transforms=self._moving)
        self._pose_msg = PoseStamped()
        self._pose_msg.header.frame_id = self._frame(WORLD_FRAME)

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

    def publish(self, stamp: Time, positions: Sequence[float],
                ball_pose: tuple[Sequence[float], Sequence[float]]) -> None:
        """Publish /tf for joint ``positions`` (joint_states order) and the ball's pose."""
        moving = self._tree.transforms([positions[i] for i in self._order])
        for message, prismatic, (_, _, translation, rotation) in zip(
                self._moving, self._prismatic, moving):
            message.header.stamp = stamp
            if prismatic:
                t = message.transform.translation
                t.x, t.y, t.z = translation
            else:
                r = message.transform.rotation
                r.x, r.y, r.z, r.w = rotation
        self._tf_pub.publish(self._tf_msg)
        pose = self._pose_msg
        pose.header.stamp = stamp
        (p, o) = ball_pose
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = p
        q = pose.pose.orientation
        q.x, q.y, q.z, q.w = o
        self._true_pose_pub.publish(pose)


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

