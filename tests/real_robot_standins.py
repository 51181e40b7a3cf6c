"""Stand-ins for a real UR cell, for the real-robot rehearsal and the UR-description tests.

- :func:`ur_description`: robot description text shaped as Universal Robots' ``ur_macro.xacro``
  (ur_description 2.4.5, BSD-3-Clause) renders it through ``ur.urdf.xacro``, written here from
  the published facts it is made of, not copied: the links and joints of its chain (``world``
  -> ``base_link`` -> ``base_link_inertia`` -> ``shoulder_link`` ... ``wrist_3_link`` ->
  ``flange`` -> ``tool0``, and ``base``, ``ft_frame``), the joint origins that its
  ``config/<model>/default_kinematics.yaml`` gives for the UR5, UR3, UR5e and UR3e (UR's
  DH parameters), and the limits of ``config/<model>/joint_limits.yaml`` (a UR3's wrist 3 is
  continuous); no mesh, no inertia. Checked against ur_description 2.4.5's own
  ``ur.urdf.xacro`` rendered with xacro 2.1.1 (PyPI) for each model: every joint's type,
  parent, child, origin, axis and limits the same (tests/test_motion_ur_descriptions.py does
  that check where ur_description is installed).
- :func:`chain_pose`: forward kinematics along a description's joints (origins and axes),
  written apart from ur_rg2_motion.kinematics as an independent judge.
- rclpy stand-ins shaped as the real drivers: :class:`UrDriver` (ur_robot_driver: its
  description, ``joint_states`` and robot_state_publisher's ``/tf``, the
  ``scaled_joint_trajectory_controller`` with ur_controllers.yaml's tolerances, the speed
  slider, an inactive controller), :class:`OnRobotGripper` (onrobot-ros2's
  ``ParallelGripperCommand`` controller on the ``grip_stroke`` joint) and :class:`RealSense`
  (realsense2_camera's ``/camera/camera/...`` topics, depth aligned to colour in 16UC1 mm)
  showing a synthetic ball.
"""

from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
import math
import threading
import time
import xml.etree.ElementTree as ET

from control_msgs.action import FollowJointTrajectory, ParallelGripperCommand
from geometry_msgs.msg import TransformStamped
import numpy as np
from rclpy.action import CancelResponse, GoalResponse
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image, JointState
from std_msgs.msg import Float64, String
from tf2_msgs.msg import TFMessage
from ur_rg2_common.action_server import WorkerActionServer
from ur_rg2_common.contract import ARM_JOINTS, LATCHED_QOS
from ur_rg2_common.tf_buffer import pose_matrix, quaternion_from_matrix

MODELS = ('ur5', 'ur3', 'ur5e', 'ur3e')
# default_kinematics.yaml's values per model: d1, a2, a3, d4, d5, d6 (m).
_KINEMATICS = {
    'ur5': (0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823),
    'ur3': (0.1519, -0.24365, -0.21325, 0.11235, 0.08535, 0.0819),
    'ur5e': (0.1625, -0.425, -0.3922, 0.1333, 0.0997, 0.0996),
    'ur3e': (0.15185, -0.24355, -0.2132, 0.13105, 0.08535, 0.0921),
}
_HALF_PI = 1.570796327  # as default_kinematics.yaml writes it
ONROBOT_ACTION = 'onrobot/gripper_controller/gripper_cmd'
ONROBOT_JOINT_STATES = 'onrobot/joint_states'
SCALED_ACTION = 'scaled_joint_trajectory_controller/follow_joint_trajectory'
# ur_robot_driver's config/ur_controllers.yaml, scaled_joint_trajectory_controller.constraints.
STOPPED_VELOCITY_TOLERANCE = 0.2  # rad/s
TRAJECTORY_TOLERANCE = 0.2  # rad, every joint
GOAL_TOLERANCE = 0.1  # rad, every joint
RG2_STROKE = 0.110  # m


def action_remaps(ours: str = 'joint_trajectory_controller/follow_joint_trajectory',
                  theirs: str = SCALED_ACTION) -> list[str]:
    """Return the ROS arguments that remap an action's five topics and services (Jazzy)."""
    arguments = []
    for part in ('_action/send_goal', '_action/cancel_goal', '_action/get_result',
                 '_action/feedback', '_action/status'):
        arguments += ['-r', f'{ours}/{part}:={theirs}/{part}']
    return arguments


def ur_description(model: str, base_height: float = 0.0) -> str:
    """Return the URDF text of UR's description of ``model`` on ``world`` (no gripper).

    ``base_height``: the origin of ``base_joint`` (world -> base_link), a pedestal.
    """
    d1, a2, a3, d4, d5, d6 = _KINEMATICS[model]
    ur3 = model.startswith('ur3')
    origins = {  # joint: (xyz, rpy), default_kinematics.yaml's
        'shoulder_pan_joint': ((0, 0, d1), (0, 0, 0)),
        'shoulder_lift_joint': ((0, 0, 0), (_HALF_PI, 0, 0)),
        'elbow_joint': ((a2, 0, 0), (0, 0, 0)),
        'wrist_1_joint': ((a3, 0, d4), (0, 0, 0)),
        'wrist_2_joint': ((0, -d5, 0), (_HALF_PI, 0, 0)),
        'wrist_3_joint': ((0, d6, 0), (1.570796326589793, math.pi, math.pi)),
    }
    parents = ('base_link_inertia', 'shoulder_link', 'upper_arm_link', 'forearm_link',
               'wrist_1_link', 'wrist_2_link', 'wrist_3_link')
    links = ['world', 'base_link', *parents, 'ft_frame', 'base', 'flange', 'tool0']
    joints = [('base_joint', 'fixed', 'world', 'base_link', (0, 0, base_height), (0, 0, 0)),
              ('base_link-base_link_inertia', 'fixed', 'base_link', 'base_link_inertia',
               (0, 0, 0), (0, 0, math.pi))]
    for i, name in enumerate(ARM_JOINTS):
        xyz, rpy = origins[name]
        kind = 'continuous' if ur3 and name == 'wrist_3_joint' else 'revolute'
        joints.append((name, kind, parents[i], parents[i + 1], xyz, rpy))
    joints += [('wrist_3_link-ft_frame', 'fixed', 'wrist_3_link', 'ft_frame', (0, 0, 0),
                (math.pi, 0, 0)),
               ('base_link-base_fixed_joint', 'fixed', 'base_link', 'base', (0, 0, 0),
                (0, 0, math.pi)),
               ('wrist_3-flange', 'fixed', 'wrist_3_link', 'flange', (0, 0, 0),
                (0, -math.pi / 2, -math.pi / 2)),
               ('flange-tool0', 'fixed', 'flange', 'tool0', (0, 0, 0),
                (math.pi / 2, 0, math.pi / 2))]
    robot = ET.Element('robot', name=model)
    for link in links:
        ET.SubElement(robot, 'link', name=link)
    for name, kind, parent, child, xyz, rpy in joints:
        joint = ET.SubElement(robot, 'joint', name=name, type=kind)
        ET.SubElement(joint, 'parent', link=parent)
        ET.SubElement(joint, 'child', link=child)
        ET.SubElement(joint, 'origin', xyz=' '.join(map(repr, map(float, xyz))),
                      rpy=' '.join(map(repr, map(float, rpy))))
        if kind != 'fixed':
            ET.SubElement(joint, 'axis', xyz='0 0 1')
            wrist = name.startswith('wrist')
            velocity = math.radians(360.0 if ur3 and wrist else 180.0)
            limit = {'effort': '150.0', 'velocity': repr(velocity)}
            if kind == 'revolute':
                bound = math.pi if name == 'elbow_joint' else 2 * math.pi
                limit.update(lower=repr(-bound), upper=repr(bound))
            ET.SubElement(joint, 'limit', **limit)
    return ET.tostring(robot, encoding='unicode')


def _rpy(xyz: Sequence[float], rpy: Sequence[float]) -> np.ndarray:
    (roll, pitch, yaw) = rpy
    rx = np.array([[1, 0, 0], [0, math.cos(roll), -math.sin(roll)],
                   [0, math.sin(roll), math.cos(roll)]])
    ry = np.array([[math.cos(pitch), 0, math.sin(pitch)], [0, 1, 0],
                   [-math.sin(pitch), 0, math.cos(pitch)]])
    rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0],
                   [0, 0, 1]])
    m = np.eye(4)
    m[:3, :3] = rz @ ry @ rx
    m[:3, 3] = xyz
    return m


class Chain:
    """A description's joints, for forward kinematics to any link."""

    def __init__(self, urdf: str) -> None:
        self.joints = {}  # child -> (name, type, parent, origin, axis)
        for joint in ET.fromstring(urdf).iter('joint'):
            origin = joint.find('origin')
            axis = joint.find('axis')
            self.joints[joint.find('child').get('link')] = (
                joint.get('name'), joint.get('type'), joint.find('parent').get('link'),
                _rpy([float(v) for v in origin.get('xyz').split()],
                     [float(v) for v in origin.get('rpy').split()]),
                np.array([float(v) for v in axis.get('xyz').split()]) if axis is not None
                else None)

    def pose(self, positions: dict[str, float], root: str, link: str) -> np.ndarray:
        """Return ``root`` -> ``link`` at joint ``positions`` (name: rad)."""
        pose = np.eye(4)
        while link != root:
            name, kind, parent, origin, axis = self.joints[link]
            motion = np.eye(4)
            if kind != 'fixed':
                # Rodrigues' formula about the joint's axis.
                k = axis / np.linalg.norm(axis)
                cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
                angle = positions[name]
                motion[:3, :3] = (np.eye(3) + math.sin(angle) * cross
                                  + (1 - math.cos(angle)) * cross @ cross)
            pose = origin @ motion @ pose
            link = parent
        return pose


def chain_pose(urdf: str, joints: Sequence[float], link: str = 'tool0') -> np.ndarray:
    """Return ``base_link`` -> ``link`` along the description's chain at the arm ``joints``."""
    return Chain(urdf).pose(dict(zip(ARM_JOINTS, joints)), 'base_link', link)


def _transform(parent: str, child: str, pose: np.ndarray, stamp) -> TransformStamped:
    message = TransformStamped()
    message.header.frame_id, message.header.stamp = parent, stamp
    message.child_frame_id = child
    t = message.transform.translation
    t.x, t.y, t.z = (float(v) for v in pose[:3, 3])
    r = message.transform.rotation
    r.x, r.y, r.z, r.w = quaternion_from_matrix(pose)
    return message


class UrDriver(Node):
    """ur_robot_driver as our nodes meet it, at 100 Hz of wall time.

    Publishes ``robot_description`` (latched), ``joint_states`` (the six arm joints, position
    and velocity) and, as robot_state_publisher does, each moving joint's transform on ``/tf``
    and the fixed ones on ``/tf_static``; ``speed_scaling_state_broadcaster/speed_scaling``
    (percent). Serves ``scaled_joint_trajectory_controller/follow_joint_trajectory``: the
    trajectory's time runs at ``speed_scaling`` (the pendant's slider, 0-1); the arm follows
    the interpolated setpoint with a first-order lag; the goal is aborted when a joint falls
    more than ur_controllers.yaml's trajectory tolerance behind, and succeeds once every joint
    is within its goal tolerance and slower than its stopped-velocity tolerance (its
    goal_time is 0: no limit). With ``active`` false (the External Control program not
    running: the driver's controller stopper has deactivated the controller) goals are
    rejected.
    """

    RATE = 100.0  # Hz
    LAG = 0.03  # s, the arm's first-order lag behind the setpoint

    def __init__(self, urdf: str, start: Sequence[float], extra_static=(), **kwargs) -> None:
        super().__init__('ur_driver_standin', **kwargs)
        self.urdf, self.chain = urdf, Chain(urdf)
        self.speed_scaling = 1.0
        self.active = True
        self._lock = threading.Lock()
        self._q = np.array(start, dtype=float)
        self._velocity = np.zeros(6)
        self._setpoint = self._q.copy()
        self._goal = None  # (times, positions, start joints, scaled time elapsed)
        self._states = self.create_publisher(JointState, 'joint_states', 10)
        self._tf = self.create_publisher(TFMessage, '/tf', 100)
        self._scaling = self.create_publisher(
            Float64, 'speed_scaling_state_broadcaster/speed_scaling', 10)
        self.create_publisher(String, 'robot_description', LATCHED_QOS).publish(
            String(data=urdf))
        stamp = self.get_clock().now().to_msg()
        fixed = [_transform(parent, child, origin, stamp)
                 for child, (_, kind, parent, origin, _) in self.chain.joints.items()
                 if kind == 'fixed']
        fixed += [_transform(parent, child, pose, stamp) for parent, child, pose in extra_static]
        self.create_publisher(TFMessage, '/tf_static', LATCHED_QOS).publish(
            TFMessage(transforms=fixed))
        self._server = WorkerActionServer(
            self, FollowJointTrajectory, SCALED_ACTION, self._execute,
            workers=ThreadPoolExecutor(4, thread_name_prefix='standin'),
            goal_callback=self._on_goal, cancel_callback=lambda _: CancelResponse.ACCEPT)
        self.create_timer(1.0 / self.RATE, self._step)

    def joints(self) -> np.ndarray:
        with self._lock:
            return self._q.copy()

    def _on_goal(self, goal: FollowJointTrajectory.Goal) -> GoalResponse:
        if not self.active:
            self.get_logger().warning("Can't accept new action goals. Controller is not "
                                      'running.')
            return GoalResponse.REJECT
        trajectory = goal.trajectory
        if sorted(trajectory.joint_names) != sorted(ARM_JOINTS) or not trajectory.points:
            return GoalResponse.REJECT
        times = [p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec
                 for p in trajectory.points]
        if any(b <= a for a, b in zip(times, times[1:])):
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _execute(self, handle) -> FollowJointTrajectory.Result:
        trajectory = handle.request.trajectory
        order = [trajectory.joint_names.index(name) for name in ARM_JOINTS]
        times = np.array([0.0] + [p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec
                                  for p in trajectory.points])
        with self._lock:
            positions = np.array([self._setpoint] + [[p.positions[i] for i in order]
                                                     for p in trajectory.points])
            goal = self._goal = [times, positions, 0.0, None]
        result = FollowJointTrajectory.Result()
        while True:
            time.sleep(0.01)
            if not self.context.ok():
                return result  # the test's graph is shut down: end the worker thread
            with self._lock:
                outcome = goal[3]
                superseded = self._goal is not goal
            if handle.is_cancel_requested:
                with self._lock:
                    if self._goal is goal:
                        self._goal = None
                handle.canceled()
                return result
            if superseded and outcome is None:
                handle.abort()
                result.error_string = 'preempted by a new goal'
                return result
            if outcome is not None:
                result.error_code, result.error_string = outcome
                if outcome[0] == FollowJointTrajectory.Result.SUCCESSFUL:
                    handle.succeed()
                else:
                    handle.abort()
                return result

    def _step(self) -> None:
        dt = 1.0 / self.RATE
        with self._lock:
            goal = self._goal
            if goal is not None:
                times, positions = goal[0], goal[1]
                goal[2] = min(goal[2] + dt * self.speed_scaling, times[-1])
                self._setpoint = np.array([np.interp(goal[2], times, positions[:, j])
                                           for j in range(6)])
            before = self._q.copy()
            self._q += (self._setpoint - self._q) * min(1.0, dt / self.LAG)
            self._velocity = (self._q - before) / dt
            if goal is not None:
                error = np.abs(self._setpoint - self._q).max()
                if error > TRAJECTORY_TOLERANCE:
                    goal[3] = (FollowJointTrajectory.Result.PATH_TOLERANCE_VIOLATED,
                               f'path tolerance violated ({error:.3f} rad)')
                    self._goal = None
                elif (goal[2] >= goal[0][-1] and error < GOAL_TOLERANCE
                      and np.abs(self._velocity).max() < STOPPED_VELOCITY_TOLERANCE
                      and np.abs(positions[-1] - self._q).max() < GOAL_TOLERANCE):
                    goal[3] = (FollowJointTrajectory.Result.SUCCESSFUL, '')
                    self._goal = None
            q, velocity = self._q.copy(), self._velocity.copy()
        now = self.get_clock().now().to_msg()
        state = JointState(name=list(ARM_JOINTS), position=q.tolist(),
                           velocity=velocity.tolist(), effort=[0.0] * 6)
        state.header.stamp = now
        self._states.publish(state)
        positions = dict(zip(ARM_JOINTS, q))
        self._tf.publish(TFMessage(transforms=[
            _transform(parent, child, origin @ self._joint_motion(axis, positions[name]), now)
            for child, (name, kind, parent, origin, axis) in self.chain.joints.items()
            if kind != 'fixed']))
        self._scaling.publish(Float64(data=100.0 * self.speed_scaling))

    @staticmethod
    def _joint_motion(axis: np.ndarray, angle: float) -> np.ndarray:
        k = axis / np.linalg.norm(axis)
        return pose_matrix((0.0, 0.0, 0.0), (*(k * math.sin(angle / 2)), math.cos(angle / 2)))


class OnRobotGripper(Node):
    """onrobot-ros2's RG2 as the adapter meets it: ``ParallelGripperCommand`` on ``grip_stroke``.

    The action at ``onrobot/gripper_controller/gripper_cmd`` and ``grip_stroke`` (the opening,
    m) on ``onrobot/joint_states`` (the driver started in the namespace ``onrobot``). The
    stroke moves at ``SPEED`` toward the goal and stops on an object ``object_width`` wide when
    closing onto it: the goal then ends SUCCEEDED with ``stalled`` (OnRobot's controller
    config has ``allow_stalling: true``), or ABORTED with ``stalled`` when ``allow_stalling``
    is false (ros2_controllers' default).
    """

    SPEED = 0.11  # m/s
    RATE = 50.0  # Hz

    def __init__(self, **kwargs) -> None:
        super().__init__('onrobot_gripper_standin', **kwargs)
        self.object_width: float | None = None
        self.allow_stalling = True
        self.goals: list[ParallelGripperCommand.Goal] = []
        self._lock = threading.Lock()
        self._stroke = RG2_STROKE
        self._target = RG2_STROKE
        self._states = self.create_publisher(JointState, ONROBOT_JOINT_STATES, 10)
        self._server = WorkerActionServer(
            self, ParallelGripperCommand, ONROBOT_ACTION, self._execute,
            workers=ThreadPoolExecutor(2, thread_name_prefix='standin'),
            cancel_callback=lambda _: CancelResponse.ACCEPT)
        self.create_timer(1.0 / self.RATE, self._step)

    @property
    def stroke(self) -> float:
        with self._lock:
            return self._stroke

    def _blocked_at(self) -> float:
        width = self.object_width
        return width if width is not None and self._target < width <= self._stroke + 1e-9 \
            else -1.0

    def _step(self) -> None:
        with self._lock:
            step = self.SPEED / self.RATE
            floor = max(self._blocked_at(), self._target)
            if self._stroke > floor:
                self._stroke = max(floor, self._stroke - step)
            elif self._stroke < self._target:
                self._stroke = min(self._target, self._stroke + step)
            stroke = self._stroke
        state = JointState(name=['grip_stroke'], position=[stroke])
        state.header.stamp = self.get_clock().now().to_msg()
        self._states.publish(state)

    def _execute(self, handle) -> ParallelGripperCommand.Result:
        command = handle.request.command
        self.goals.append(handle.request)
        target = min(max(command.position[command.name.index('grip_stroke')], 0.0), RG2_STROKE)
        with self._lock:
            self._target = target
        result = ParallelGripperCommand.Result()
        last = None
        while True:
            time.sleep(0.05)
            if not self.context.ok():
                return result  # the test's graph is shut down: end the worker thread
            with self._lock:
                stroke, blocked = self._stroke, abs(self._stroke - self._blocked_at()) < 1e-9
            feedback = ParallelGripperCommand.Feedback()
            feedback.state = JointState(name=['grip_stroke'], position=[stroke])
            handle.publish_feedback(feedback)
            if handle.is_cancel_requested:
                handle.canceled()
                return result
            result.state = JointState(name=['grip_stroke'], position=[stroke])
            if abs(stroke - target) < 1e-4:
                result.reached_goal = True
                handle.succeed()
                return result
            if blocked and last == stroke:
                result.stalled = True
                if self.allow_stalling:
                    handle.succeed()
                else:
                    handle.abort()
                return result
            last = stroke


class RealSense(Node):
    """realsense2_camera (``rs_launch.py align_depth.enable:=true``) looking at a ball.

    ``/camera/camera/color/image_raw`` (rgb8), ``/camera/camera/color/camera_info``,
    ``/camera/camera/aligned_depth_to_color/image_raw`` (16UC1, mm; 0 where there is no
    return) and its camera_info, all stamped alike in ``camera_color_optical_frame``. The
    scene, rendered once: a grey table (the plane z = 0 of ``world``) and a red ball of
    ``radius`` at ``ball`` (world), seen from ``camera`` (world -> optical frame, 4x4).
    """

    WIDTH, HEIGHT, FOCAL = 640, 480, 600.0

    def __init__(self, camera: np.ndarray, ball: Sequence[float], radius: float,
                 rate: float = 10.0, **kwargs) -> None:
        super().__init__('realsense_standin', **kwargs)
        self._color = self.create_publisher(Image, '/camera/camera/color/image_raw', 5)
        self._info = self.create_publisher(CameraInfo, '/camera/camera/color/camera_info', 5)
        self._depth = self.create_publisher(
            Image, '/camera/camera/aligned_depth_to_color/image_raw', 5)
        self._depth_info = self.create_publisher(
            CameraInfo, '/camera/camera/aligned_depth_to_color/camera_info', 5)
        self._rgb, self._mm = self._render(camera, np.asarray(ball, dtype=float), radius)
        self.create_timer(1.0 / rate, self._publish)

    def _render(self, camera: np.ndarray, ball: np.ndarray, radius: float):
        u, v = np.meshgrid(np.arange(self.WIDTH), np.arange(self.HEIGHT))
        cx, cy = self.WIDTH / 2 - 0.5, self.HEIGHT / 2 - 0.5
        rays = np.stack([(u - cx) / self.FOCAL, (v - cy) / self.FOCAL, np.ones(u.shape)], -1)
        world_rays = rays @ camera[:3, :3].T  # direction per unit of optical z
        origin = camera[:3, 3]
        # The table: origin_z + t * ray_z = 0.
        with np.errstate(divide='ignore', invalid='ignore'):
            table = np.where(world_rays[..., 2] < 0, -origin[2] / world_rays[..., 2], np.inf)
        # The ball: |origin + t ray - ball| = radius, the nearer root.
        offset = origin - ball
        a = (world_rays ** 2).sum(-1)
        b = 2 * (world_rays @ offset)
        c = offset @ offset - radius ** 2
        disc = b * b - 4 * a * c
        with np.errstate(invalid='ignore'):
            sphere = np.where(disc >= 0, (-b - np.sqrt(disc)) / (2 * a), np.inf)
        on_ball = sphere < table
        depth = np.minimum(sphere, table)
        rgb = np.full((self.HEIGHT, self.WIDTH, 3), 128, np.uint8)
        rgb[on_ball] = (200, 20, 20)
        mm = np.where(np.isfinite(depth), np.round(depth * 1000.0), 0).astype(np.uint16)
        return rgb, mm

    def _publish(self) -> None:
        stamp = self.get_clock().now().to_msg()
        info = CameraInfo(width=self.WIDTH, height=self.HEIGHT, distortion_model='plumb_bob',
                          d=[0.0] * 5)
        cx, cy = self.WIDTH / 2 - 0.5, self.HEIGHT / 2 - 0.5
        info.k = [self.FOCAL, 0.0, cx, 0.0, self.FOCAL, cy, 0.0, 0.0, 1.0]
        info.p = [self.FOCAL, 0.0, cx, 0.0, 0.0, self.FOCAL, cy, 0.0, 0.0, 0.0, 1.0, 0.0]
        info.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        info.header.stamp, info.header.frame_id = stamp, 'camera_color_optical_frame'
        color = Image(height=self.HEIGHT, width=self.WIDTH, encoding='rgb8',
                      step=3 * self.WIDTH, data=self._rgb.tobytes())
        depth = Image(height=self.HEIGHT, width=self.WIDTH, encoding='16UC1',
                      step=2 * self.WIDTH, data=self._mm.tobytes())
        for message in (color, depth):
            message.header = info.header
        self._color.publish(color)
        self._depth.publish(depth)
        self._info.publish(info)
        self._depth_info.publish(info)


def look_at(position: Sequence[float], target: Sequence[float]) -> np.ndarray:
    """Return world -> optical frame (z toward ``target``, x right, y down) of a camera."""
    position, target = np.asarray(position, float), np.asarray(target, float)
    z = target - position
    z /= np.linalg.norm(z)
    x = np.cross(z, (0.0, 0.0, 1.0))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, y, z], axis=1)
    pose[:3, 3] = position
    return pose


def add(graph, node: Node) -> Node:
    """Spin ``node`` in the test's ``graph``, its blocking group (if any) on worker threads."""
    group = getattr(node, 'blocking_group', None)
    if group is not None:
        graph.executor.add_blocking_group(group)
    return graph.add(node)
