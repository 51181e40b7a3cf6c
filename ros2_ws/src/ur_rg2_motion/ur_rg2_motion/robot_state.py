"""The robot as the graph tells it, kept by the motion and policy nodes: one home for both.

:class:`RobotState` holds the latest ``robot_description`` (and the arm model built from it
with the floor the transform tree places), the arm joints, their speed and the RG2's opening
from ``joint_states``, the transform tree of ``/tf`` and ``/tf_static``, and the latest
``ball/position``. It reads messages by their fields only and is tested without a node;
:func:`subscribe` wires a node's subscriptions to it. The busy topics (``joint_states``,
``/tf``, ``ball/position``) wait in inboxes (ur_rg2_common.inbox) until the state is read: an
idle node does no work per message.
"""

from collections.abc import Callable, Sequence
import math
import threading
import time

from geometry_msgs.msg import PointStamped
import numpy as np
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage
from ur_rg2_common.contract import (
    ARM_JOINTS,
    GRIPPER_JOINTS,
    LATCHED_QOS,
    TF_QOS,
    WORLD_FRAME,
)
from ur_rg2_common.inbox import Inbox
from ur_rg2_common.tf_buffer import PULL_PERIOD_S, FrameLookupError, TransformBuffer

from ur_rg2_motion.kinematics import (
    FLOOR_CLEARANCE,
    PEDESTAL_HALF_WIDTH,
    ArmKinematics,
    KinematicsError,
    arm_on_pedestal,
    urdf_velocity_limits,
)
from ur_rg2_motion.messages import ball_in_base_link
from ur_rg2_motion.urdf import BASE_LINK

# Best effort (a driver's reliable joint_states match too); deep enough that an arm's and a
# gripper's joint states published apart are both among the newest (ur_rg2_common.inbox).
JOINT_STATES_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)


class NotReceivedError(KinematicsError):
    """What a request needs has not come from the graph yet (it may, later)."""

    def __init__(self, what: str, message: str | None = None) -> None:
        super().__init__('invalid', message or f'no {what} received yet')


class RobotState:
    """The latest robot_description, joint_states, transforms and ball sighting; thread-safe.

    The arm and the RG2 may come in separate ``joint_states`` messages (a real cell: the UR
    driver, and ur_rg2_hardware's ``rg2_adapter``); each message updates what it has, and
    values that are not finite are left out. ``tcp_offset``: see ArmKinematics.from_urdf.
    ``pull`` is called, holding no lock, before the joints, the gripper or the ball are read
    and while they are waited for: it adds what came since (:func:`subscribe` sets it).
    """

    def __init__(self, tcp_offset: Sequence[float] | None = None) -> None:
        self.tf = TransformBuffer()
        self.pull: Callable[[], object] = lambda: None
        self._tcp_offset = list(tcp_offset) if tcp_offset is not None else None
        # Notified when robot_description, /tf_static or the arm joints come: requests may
        # wait for them.
        self._lock = threading.Condition()
        self._urdf: str | None = None
        self._velocity_limits: np.ndarray | None = None
        self._arm: tuple[tuple, ArmKinematics] | None = None  # (what it was built from, arm)
        self._joints: np.ndarray | None = None
        self._speed = 0.0
        self._opening: float | None = None
        self._ball: tuple[float, PointStamped] | None = None  # (monotonic receipt, message)
        self._static = False  # whether a /tf_static message has come

    # -- what the graph sends ----------------------------------------------------------------

    def set_description(self, urdf: str) -> str:
        """Take ``urdf`` as the robot and return its UR model.

        KinematicsError (a ValueError) says why it is unusable; the previous one then stays.
        """
        model = ArmKinematics.from_urdf(urdf, tcp_offset=self._tcp_offset).model
        limits = urdf_velocity_limits(urdf)
        with self._lock:
            self._urdf, self._velocity_limits = urdf, limits
            self._lock.notify_all()
        return model

    def add_joint_state(self, message: JointState) -> None:
        """Take what ``message`` says of the six arm joints and of the RG2's fingers."""
        positions = dict(zip(message.name, message.position))
        speeds = dict(zip(message.name, message.velocity))
        if all(name in positions for name in ARM_JOINTS):
            joints = np.array([positions[name] for name in ARM_JOINTS], dtype=float)
            speed = max(abs(speeds.get(name, 0.0)) for name in ARM_JOINTS)
            if np.isfinite(joints).all():
                with self._lock:
                    self._joints = joints
                    self._speed = speed if math.isfinite(speed) else math.inf
                    self._lock.notify_all()
        if all(name in positions for name in GRIPPER_JOINTS):
            opening = float(sum(positions[name] for name in GRIPPER_JOINTS))
            if math.isfinite(opening):
                with self._lock:
                    self._opening = opening

    def add_static(self, message: TFMessage) -> None:
        """Take a latched ``/tf_static`` message (the fixed frames: the floor, the pedestal)."""
        self.tf.add_message(message)
        with self._lock:
            self._static = True
            self._lock.notify_all()

    def add_ball(self, message: PointStamped, received: float | None = None) -> None:
        """Take a ``ball/position`` message as the latest sighting.

        ``received``: when it came (``time.monotonic()``), now by default.
        """
        with self._lock:
            self._ball = (time.monotonic() if received is None else received, message)
            self._lock.notify_all()

    def _wait_for(self, predicate: Callable[[], bool], wait: float) -> None:
        """Pull until ``predicate`` (called holding the lock) is true, or ``wait`` s pass."""
        deadline = time.monotonic() + wait
        while True:
            self.pull()
            with self._lock:
                remaining = deadline - time.monotonic()
                if predicate() or remaining <= 0:
                    return
                self._lock.wait(min(remaining, PULL_PERIOD_S))

    # -- what the nodes ask ------------------------------------------------------------------

    @property
    def urdf(self) -> str | None:
        """The robot_description in use, None before the first usable one."""
        with self._lock:
            return self._urdf

    @property
    def velocity_limits(self) -> np.ndarray | None:
        """The six arm joints' velocity limits from robot_description (rad/s), or None."""
        with self._lock:
            return self._velocity_limits

    @property
    def ball(self) -> PointStamped | None:
        """The latest ``ball/position`` message, None before the first."""
        self.pull()
        with self._lock:
            return None if self._ball is None else self._ball[1]

    def joints(self, wait: float = 0.0) -> np.ndarray:
        """Return the arm joints (rad).

        NotReceivedError when no joint_states has come, after waiting up to ``wait`` s for one.
        """
        self._wait_for(lambda: self._joints is not None, wait)
        with self._lock:
            joints = self._joints
        if joints is None:
            raise NotReceivedError('joint_states')
        return joints

    def speed(self) -> float:
        """Return the fastest arm joint's speed (rad/s; 0 before the first joint_states)."""
        self.pull()
        with self._lock:
            return self._speed

    def opening(self) -> float | None:
        """Return the RG2's opening (m, the sum of its finger joints), None before the first."""
        self.pull()
        with self._lock:
            return self._opening

    def ball_centre(self, max_age: float, wait: float = 0.0) -> np.ndarray:
        """Return the ball's centre in base_link from the latest sighting (ValueError why not).

        The sighting must be at most ``max_age`` s old; before the first one has come (a node
        just started) it is waited for up to ``wait`` s. Its frame is waited for a bounded
        moment (messages.FRAME_WAIT_S).
        """
        self._wait_for(lambda: self._ball is not None, wait)
        with self._lock:
            ball = self._ball
        return ball_in_base_link(self.tf, ball, max_age)

    def kinematics(self, pedestal_half_width: float = PEDESTAL_HALF_WIDTH,
                   clearance: float = FLOOR_CLEARANCE, wait: float = 0.0) -> ArmKinematics:
        """Return the arm model with the floor and pedestal where the tree has them now.

        The floor is ``world`` in the tree; without it the arm has no floor (``floor_z`` -inf:
        a real cell). NotReceivedError without a robot_description, or before the first
        /tf_static (the arm's links may come on /tf before the latched ``world`` ->
        ``base_link`` does), after waiting up to ``wait`` s for them.
        """
        with self._lock:
            self._lock.wait_for(lambda: self._urdf is not None and self._static, wait)
            urdf, static = self._urdf, self._static
        if urdf is None:
            raise NotReceivedError('robot_description')
        try:
            height = float(self.tf.lookup(WORLD_FRAME, BASE_LINK)[2, 3])
        except FrameLookupError:
            if not static:
                raise NotReceivedError('/tf_static') from None
            height = math.inf  # no world frame in the tree: no floor known
        key = (urdf, height, pedestal_half_width, clearance)
        with self._lock:
            if self._arm is not None and self._arm[0] == key:
                return self._arm[1]
        arm = arm_on_pedestal(urdf, height, pedestal_half_width, clearance, self._tcp_offset)
        with self._lock:
            self._arm = (key, arm)
        return arm


def subscribe(node: Node, state: RobotState,
              on_description: Callable[[String], None]) -> None:
    """Subscribe ``node`` to what ``state`` keeps.

    robot_description goes to ``on_description``, which hands it to
    ``state.set_description`` and logs the outcome. ``/tf``, ``joint_states`` and
    ``ball/position`` wait in inboxes that ``state`` pulls when it is read.
    """
    node.create_subscription(String, 'robot_description', on_description, LATCHED_QOS)
    node.create_subscription(TFMessage, '/tf_static', state.add_static, LATCHED_QOS)
    tf = Inbox(node, TFMessage, '/tf', TF_QOS, lambda data, _: state.tf.add_serialized(data),
               raw=True)
    joints = Inbox(node, JointState, 'joint_states', JOINT_STATES_QOS,
                   lambda message, _: state.add_joint_state(message))
    # Only the latest sighting counts.
    ball = Inbox(node, PointStamped, 'ball/position', 1,
                 lambda message, arrival: state.add_ball(message, arrival.received))
    state.tf.pull = tf.pull
    state.pull = lambda: (joints.pull(), ball.pull())
