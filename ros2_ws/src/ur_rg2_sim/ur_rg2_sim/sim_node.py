"""ROS 2 node ``ur_rg2_sim``: wires the pybullet simulation to topics, services, parameters."""

from array import array
from collections.abc import Sequence
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass
import math
import os
import sys
from typing import Optional

from builtin_interfaces.msg import Time
from rcl_interfaces.msg import SetParametersResult
import rclpy
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, JointState
from std_msgs.msg import Header
from std_srvs.srv import Trigger
from ur_rg2_common.contract import ARM_JOINTS
from ur_rg2_common.parameters import declare_parameters
from ur_rg2_common.scene_objects import SceneObject
from ur_rg2_common.spin import run_node

from ur_rg2_sim.camera import Camera, CameraConfig, Frame
from ur_rg2_sim.commands import CommandError, finite_vector, in_range, joint_targets
from ur_rg2_sim.controllers import Controllers
from ur_rg2_sim.frame_publisher import FramePublisher
from ur_rg2_sim.frames import OPTICAL_FRAME, load_frame_tree, robot_description
from ur_rg2_sim.planning import CollisionModel
from ur_rg2_sim.robot_model import ROBOT_MODELS, RobotModelError
from ur_rg2_sim.safety import Homing, ProtectiveStop, describe
from ur_rg2_sim.serialized import SerializedMessage
from ur_rg2_sim.simulation import NS, Schedule, SimulationLoop
from ur_rg2_sim.world import (
    DEFAULT_BALL_POSITION,
    Contact,
    JointStateSample,
    SimWorld,
    WorldConfig,
)

# Gripper and reset services give up after this much simulation time (the contract's 5 s).
SERVICE_TIMEOUT = 5.0
# The fingers count as stopped once they have not moved for this long.
GRIPPER_SETTLE_TIME = 0.1

# Images are large (640x480 rgb8 is 900 KiB) and cross processes: best-effort readers lose
# most UDP fragments, so the camera publishes reliably with a short queue; a slow reader then
# costs it at most a few frames of memory, never the sim's pace.
IMAGE_QOS = QoSProfile(depth=5, history=HistoryPolicy.KEEP_LAST,
                       reliability=ReliabilityPolicy.RELIABLE)

_PARAMETERS = (
    # name, default, description, read-only
    ('robot_model', 'ur5', f"UR arm model: {' or '.join(ROBOT_MODELS)}", True),
    ('gui', False, 'Open the pybullet GUI window (needs a display)', True),
    ('real_time_factor', 1.0, 'Simulation speed relative to the wall clock; 0 = as fast as '
     'possible', False),
    ('physics_rate', 240.0, 'Physics steps per second of simulation time', True),
    ('joint_state_rate', 100.0, 'joint_states rate, Hz of simulation time', False),
    ('camera_rate', 30.0, 'Camera frame rate, Hz of simulation time; 0 turns the camera off',
     False),
    ('camera_width', 640, 'Image width, pixels', False),
    ('camera_height', 480, 'Image height, pixels', False),
    ('camera_hfov', 57.0, 'Horizontal field of view, degrees (Kinect v1: 57)', False),
    ('camera_position', list(CameraConfig.position), 'Camera position [x, y, z], world frame, m',
     False),
    ('camera_look_at', list(CameraConfig.look_at), 'Point the camera looks at [x, y, z], world '
     'frame, m', False),
    ('ball_position', list(DEFAULT_BALL_POSITION), 'Ball centre [x, y, z], world frame, m; '
     'setting it moves the ball there at rest', False),
    ('ball_radius', 0.03, 'Ball radius, m', True),
    ('ball_color', [1.0, 0.0, 0.0, 1.0], 'Ball colour [r, g, b, a], 0-1', False),
    ('floor_color', [c / 255 for c in CameraConfig.floor_colors[0]], 'Floor colour [r, g, b], '
     '0-1 (its tiles alternate with a darker shade)', False),
    ('light_direction', list(CameraConfig.light_direction), 'Direction toward the light [x, y, '
     'z], world frame (brightness and shading of everything the camera sees)', False),
    ('scene_objects', '', 'Static objects on the floor that are not balls (cubes, boxes, flat '
     'discs; e.g. for a detector data set), separated by ";": "box|disc x y yaw size1 size2 '
     'size3 r g b" (world m, rad; box: half extents; disc: radius, unused, half height; '
     'colour 0-1); setting it replaces the previous ones', False),
    ('home_position', [0.0] * len(ARM_JOINTS), 'Arm home pose for reset, rad, joint order of '
     'joint_states', False),
    ('frame_prefix', '', 'Prepended to every frame id the sim publishes (several robots on one '
     'graph)', True),
)


@dataclass(frozen=True)
class SimSettings:
    """Validated parameter values."""

    robot_model: str
    gui: bool
    real_time_factor: float
    physics_rate: float
    joint_state_rate: float
    camera_rate: float
    camera_width: int
    camera_height: int
    camera_hfov: float
    camera_position: tuple[float, ...]
    camera_look_at: tuple[float, ...]
    ball_position: tuple[float, ...]
    ball_radius: float
    ball_color: tuple[float, ...]
    floor_color: tuple[float, ...]
    light_direction: tuple[float, ...]
    scene_objects: tuple[SceneObject, ...]
    home_position: tuple[float, ...]
    frame_prefix: str

    @classmethod
    def from_values(cls, values: dict) -> 'SimSettings':
        """Validate raw parameter values; raise CommandError naming the first bad one."""
        if values['robot_model'] not in ROBOT_MODELS:
            raise CommandError(f"robot_model must be {' or '.join(ROBOT_MODELS)}, "
                               f"got {values['robot_model']!r}")
        physics_rate = in_range('physics_rate', values['physics_rate'], 10.0, 10000.0)
        color = finite_vector('ball_color', values['ball_color'], 4)
        if not all(0.0 <= c <= 1.0 for c in color):
            raise CommandError(f'ball_color values must be between 0 and 1, got {list(color)}')
        floor = finite_vector('floor_color', values['floor_color'], 3)
        if not all(0.0 <= c <= 1.0 for c in floor):
            raise CommandError(f'floor_color values must be between 0 and 1, got {list(floor)}')
        light = finite_vector('light_direction', values['light_direction'], 3)
        if not any(light):
            raise CommandError('light_direction must not be zero')
        try:
            objects = tuple(SceneObject.parse(values['scene_objects']))
        except ValueError as error:
            raise CommandError(str(error)) from None
        return cls(
            robot_model=values['robot_model'],
            gui=values['gui'],
            real_time_factor=in_range('real_time_factor', values['real_time_factor'], 0.0, 1e3),
            physics_rate=physics_rate,
            joint_state_rate=in_range('joint_state_rate', values['joint_state_rate'], 0.1,
                                      physics_rate),
            camera_rate=in_range('camera_rate', values['camera_rate'], 0.0, physics_rate),
            camera_width=int(in_range('camera_width', values['camera_width'], 1, 4096)),
            camera_height=int(in_range('camera_height', values['camera_height'], 1, 4096)),
            camera_hfov=in_range('camera_hfov', values['camera_hfov'], 1.0, 170.0),
            camera_position=finite_vector('camera_position', values['camera_position'], 3),
            camera_look_at=finite_vector('camera_look_at', values['camera_look_at'], 3),
            ball_position=finite_vector('ball_position', values['ball_position'], 3),
            ball_radius=in_range('ball_radius', values['ball_radius'], 0.005, 0.5),
            ball_color=color,
            floor_color=floor,
            light_direction=light,
            scene_objects=objects,
            home_position=finite_vector('home_position', values['home_position'],
                                        len(ARM_JOINTS)),
            frame_prefix=values['frame_prefix'],
        )

    def camera_config(self) -> CameraConfig:
        """Return the camera settings."""
        return CameraConfig(width=self.camera_width, height=self.camera_height,
                            hfov_deg=self.camera_hfov, position=self.camera_position,
                            look_at=self.camera_look_at,
                            floor_colors=(_shade(self.floor_color, 255),
                                          _shade(self.floor_color, 218)),
                            light_direction=self.light_direction)

    def schedule(self) -> Schedule:
        """Return the output rates and pacing."""
        return Schedule(self.joint_state_rate, self.camera_rate, self.real_time_factor)


class SimNode(Node):
    """Simulated UR arm with an RG2 gripper and an RGB-D camera, per the INTERFACES contract."""

    def __init__(self, **kwargs) -> None:
        super().__init__('ur_rg2_sim', **kwargs)
        self.settings = SimSettings.from_values(declare_parameters(self, _PARAMETERS))
        s = self.settings
        gui = s.gui and bool(os.environ.get('DISPLAY') or os.environ.get('WAYLAND_DISPLAY'))
        if s.gui and not gui:
            self.get_logger().warning('gui requested but there is no display: running headless')
        self._world = SimWorld(WorldConfig(
            robot_model=s.robot_model, physics_rate=s.physics_rate,
            ball_position=s.ball_position, ball_radius=s.ball_radius, ball_color=s.ball_color,
            home_position=s.home_position, gui=gui))

        self._clock_pub = self.create_publisher(Clock, '/clock', 10)
        self._clock_msg = Clock()
        self._joint_pub = self.create_publisher(JointState, 'joint_states', 10)
        self._joint_msg = SerializedMessage(
            lambda doubles, words: _joint_state(self._world.joint_names, doubles, words),
            3 * len(self._world.joint_names), 2)
        self._color_pub = self.create_publisher(Image, 'camera/color/image_raw', IMAGE_QOS)
        self._color_info_pub = self.create_publisher(
            CameraInfo, 'camera/color/camera_info', IMAGE_QOS)
        self._depth_pub = self.create_publisher(Image, 'camera/depth/image_raw', IMAGE_QOS)
        self._depth_info_pub = self.create_publisher(
            CameraInfo, 'camera/depth/camera_info', IMAGE_QOS)
        self._color_frame = s.frame_prefix + OPTICAL_FRAME
        self._frames = FramePublisher(
            self, load_frame_tree(self._world, self._world.urdf),
            robot_description(self._world.urdf), s.frame_prefix, self._world.joint_names)
        self._frames.publish_static(_stamp(0), s.camera_position, s.camera_look_at)

        # Jogs are relative: a burst of key presses must not lose any.
        self.create_subscription(JointState, 'joint_jog', self._on_jog, 100)
        self.create_subscription(JointState, 'joint_command', self._on_command, 100)
        # Services wait for the simulation: in this reentrant group they may wait side by side
        # on worker threads (see BlockingGroupExecutor) while subscriptions keep being served.
        self.blocking_group = ReentrantCallbackGroup()
        for name, callback in (('gripper/open', self._on_gripper_open),
                               ('gripper/close', self._on_gripper_close),
                               ('reset', self._on_reset)):
            self.create_service(Trigger, name, callback, callback_group=self.blocking_group)
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self._sim = SimulationLoop(self._world, self, s.schedule(), self._make_camera(s))
        self._controllers = Controllers(self, self._sim)
        # Where reset plans its way round, made now rather than at the first blocked reset:
        # 33 MB (a pybullet client's own) taken at start-up, not in the middle of a run.
        self._reset_model = CollisionModel(s.robot_model)
        # Reset's way home; a trajectory started since ends it (the others end it in
        # _command_arm).
        self._homing = Homing(self._reset_model, self._on_no_way_home)
        self._sim.step_hooks.append(self._step_homing)
        # After the controllers and homing: it judges the targets they have just set.
        self._sim.step_hooks.append(ProtectiveStop(self._on_protective_stop).step)
        self._sim.start()
        self.get_logger().info(
            f'simulating {s.robot_model} + RG2 at {s.physics_rate:g} Hz, real-time factor '
            f'{s.real_time_factor:g}, camera {s.camera_width}x{s.camera_height} at '
            f'{s.camera_rate:g} Hz')

    def destroy_node(self) -> None:
        """Stop the simulation thread and release pybullet."""
        logger = self.get_logger()
        stopped = self._sim.stop()
        self._controllers.close()
        if stopped:
            self._reset_model.close()
            self._world.close()
        else:
            # pybullet is not thread-safe: disconnecting under a running step can abort the
            # process. The thread is a daemon, so the process still exits.
            logger.error('the simulation thread did not stop; leaving pybullet connected')
        super().destroy_node()
        # Logged after the node is gone: its rosout publisher may already be dead (a signal
        # shuts the context down first), and this line is for the console anyway.
        logger.info(self._sim.summary())

    @property
    def simulation_error(self) -> Optional[BaseException]:
        """Return the exception that stopped the simulation thread, if any."""
        return self._sim.error

    # -- outputs (simulation thread) ----------------------------------------------------------

    def clock(self, stamp_ns: int) -> None:
        """Publish ``/clock``."""
        self._clock_msg.clock = _stamp(stamp_ns)
        self._clock_pub.publish(self._clock_msg)

    def joint_states(self, stamp_ns: int, sample: JointStateSample) -> None:
        """Publish ``joint_states``."""
        # At real-time factor 0 this runs thousands of times a second: serialized bytes.
        stamp = _stamp(stamp_ns)
        self._joint_pub.publish(self._joint_msg.fill(
            (*sample.positions, *sample.velocities, *sample.efforts),
            (stamp.sec, stamp.nanosec)))
        self._frames.publish(stamp, sample.positions, self._world.body_pose(self._world.ball))

    def frame(self, stamp_ns: int, camera: Camera, frame: Frame) -> None:
        """Publish colour, depth and their camera_info with one header."""
        height, width = frame.depth.shape
        color = Image(height=height, width=width, encoding='rgb8', step=width * 3)
        color.header.stamp = _stamp(stamp_ns)
        color.header.frame_id = self._color_frame
        color.data = frame.rgb.tobytes()
        depth = Image(header=color.header, height=height, width=width, encoding='32FC1',
                      is_bigendian=sys.byteorder == 'big', step=width * 4)
        depth.data = frame.depth.tobytes()
        info = _camera_info(camera, color.header)
        self._color_pub.publish(color)
        self._color_info_pub.publish(info)
        self._depth_pub.publish(depth)
        self._depth_info_pub.publish(info)

    # -- commands -----------------------------------------------------------------------------

    def _on_jog(self, msg: JointState) -> None:
        self._apply_joint_message('joint_jog', msg, SimWorld.jog_arm)

    def _on_command(self, msg: JointState) -> None:
        self._apply_joint_message('joint_command', msg, SimWorld.move_arm)

    def _apply_joint_message(self, topic: str, msg: JointState, apply) -> None:
        try:
            targets = joint_targets(msg.name, msg.position, ARM_JOINTS)
        except CommandError as error:
            self.get_logger().warning(f'{topic} rejected: {error}')
            return
        self._command_arm(topic, lambda world: apply(world, targets))

    def _command_arm(self, source: str, apply):
        """Run ``apply(world)`` on the simulation thread, preempting a running trajectory."""
        def command(world: SimWorld):
            self._controllers.arm_commanded(source)
            self._homing.cancel()
            return apply(world)
        return self._sim.call(command)

    def _step_homing(self, world: SimWorld, _now_ns: int) -> None:
        if self._controllers.arm_running:
            self._homing.cancel()
        else:
            self._homing.step(world)

    def _on_no_way_home(self, held: list[float]) -> None:
        self.get_logger().warning(
            f'reset: no way home clear of the floor, the pedestal and the arm itself from '
            f'{degrees_list(held)} deg; the arm holds there. Jog it clear and reset again')

    def _on_protective_stop(self, contact: Contact, held: dict[str, float], new: bool) -> None:
        """Report a stop: abort the running trajectory, tell homing, warn once (sim thread)."""
        self._homing.blocked()
        message = (f'protective stop: {describe(contact)} ({contact.force:.0f} N); the arm '
                   f'holds at {degrees_list(held.values())} deg. Commands that move it away '
                   '(reset, a jog or trajectory back) are obeyed')
        self._controllers.arm_blocked(message)
        if new:
            self.get_logger().warning(message)

    def _on_gripper_open(self, request: Trigger.Request,
                         response: Trigger.Response) -> Trigger.Response:
        return self._run_gripper(response, SimWorld.open_gripper)

    def _on_gripper_close(self, request: Trigger.Request,
                          response: Trigger.Response) -> Trigger.Response:
        return self._run_gripper(response, SimWorld.close_gripper)

    def _run_gripper(self, response: Trigger.Response, action) -> Trigger.Response:
        stopped = self._sim.wait_until(action, SimWorld.gripper_stopped, SERVICE_TIMEOUT,
                                       hold_s=GRIPPER_SETTLE_TIME)
        report = self._sim_result(stopped)
        if report is not True:
            response.success = False
            response.message = report or 'the fingers did not stop within 5 s of simulation time'
            return response
        state = self._sim_result(self._sim.call(
            lambda world: (world.gripper_target, world.gripper_opening(),
                           world.gripper_holds_object())))
        if isinstance(state, str):
            response.success, response.message = False, state
            return response
        target, opening, holds = state
        response.success = True
        if target > 0:
            response.message = f'opened: {opening * 1000:.1f} mm between the fingers'
        elif holds:
            response.message = f'grasped an object: fingers stopped at {opening * 1000:.1f} mm'
        else:
            response.message = f'closed: nothing grasped ({opening * 1000:.1f} mm)'
        return response

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        home = dict(zip(ARM_JOINTS, self.settings.home_position))
        applied = self._sim_result(
            self._command_arm('reset', lambda world: self._homing.start(world, home)))
        if isinstance(applied, str):
            response.success, response.message = False, applied
            return response
        response.success = True
        response.message = f'arm going home: {degrees_list(applied.values())} deg'
        return response

    def _sim_result(self, future):
        """Return a simulation future's result, or a sentence saying why there is none."""
        # 5 s of simulation time take 5 s / real_time_factor of wall time, plus a margin for
        # a loaded machine; with factor 0 the simulation is faster than real time anyway.
        rtf = self.settings.real_time_factor
        wall_timeout = SERVICE_TIMEOUT / rtf + 5.0 if rtf > 0 else SERVICE_TIMEOUT + 5.0
        try:
            return future.result(timeout=wall_timeout)
        except FutureTimeout:
            return 'the simulation did not answer in time'
        except RuntimeError as error:
            return str(error)

    # -- parameters ---------------------------------------------------------------------------

    def _on_set_parameters(self, parameters: Sequence[Parameter]) -> SetParametersResult:
        values = {name: self.get_parameter(name).value for name, *_ in _PARAMETERS}
        values.update({p.name: p.value for p in parameters})
        try:
            settings = SimSettings.from_values(values)
        except (TypeError, ValueError) as error:  # CommandError is a ValueError
            self.get_logger().warning(f'parameter change rejected: {error}')
            return SetParametersResult(successful=False, reason=str(error))
        previous, self.settings = self.settings, settings
        if settings.ball_position != previous.ball_position:
            self._sim.call(lambda world: world.set_ball_position(settings.ball_position))
        if settings.ball_color != previous.ball_color:
            self._sim.call(lambda world: world.set_ball_color(settings.ball_color))
        if settings.scene_objects != previous.scene_objects:
            self._sim.call(lambda world: world.set_scene_objects(settings.scene_objects))
        if settings.schedule() != previous.schedule() or (
                settings.camera_config() != previous.camera_config()):
            self._sim.reschedule(settings.schedule(), self._make_camera(settings))
        if (settings.camera_position, settings.camera_look_at) != (
                previous.camera_position, previous.camera_look_at):
            # Queued after the new camera: every frame stamped after this /tf_static uses it.
            self._sim.call(lambda world: self._frames.publish_static(
                _stamp(self._sim.sim_time_ns), settings.camera_position, settings.camera_look_at))
        return SetParametersResult(successful=True)

    def _make_camera(self, settings: SimSettings) -> Optional[Camera]:
        if settings.camera_rate <= 0:
            return None
        return Camera(self._world, settings.camera_config())


def _shade(rgb: Sequence[float], scale: float) -> tuple[int, int, int]:
    return tuple(round(c * scale) for c in rgb)


def degrees_list(radians: Sequence[float]) -> str:
    """Return angles in radians as degrees for people, e.g. ``[0, -90, 12.5]``."""
    # + 0.0 turns a rounded -0.0 into 0.
    return '[' + ', '.join(f'{round(math.degrees(a), 1) + 0.0:g}' for a in radians) + ']'


def _joint_state(names: Sequence[str], doubles, words) -> JointState:
    count = len(names)
    return JointState(header=Header(stamp=Time(sec=int(words[0]), nanosec=int(words[1]))),
                      name=list(names), position=array('d', doubles[:count]),
                      velocity=array('d', doubles[count:2 * count]),
                      effort=array('d', doubles[2 * count:]))


def _stamp(stamp_ns: int) -> Time:
    return Time(sec=stamp_ns // NS, nanosec=stamp_ns % NS)


def _camera_info(camera: Camera, header) -> CameraInfo:
    k = camera.k
    info = CameraInfo(header=header, height=camera.config.height, width=camera.config.width,
                      distortion_model='plumb_bob')
    info.d = [0.0] * 5
    info.k = k.flatten().tolist()
    info.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    info.p = [k[0, 0], 0.0, k[0, 2], 0.0, 0.0, k[1, 1], k[1, 2], 0.0, 0.0, 0.0, 1.0, 0.0]
    return info


def main(args: Optional[list[str]] = None) -> int:
    """Run the simulator node until Ctrl-C or SIGTERM."""
    return run_node(SimNode, args, 'ur_rg2_sim',
                    startup_errors=(CommandError, RobotModelError, ParameterException),
                    on_startup_error=_invalid_parameter, failure=_simulation_failure)


def _invalid_parameter(error: Exception) -> int:
    rclpy.logging.get_logger('ur_rg2_sim').fatal(f'invalid parameter: {error}')
    return 2


def _simulation_failure(node: SimNode) -> Optional[str]:
    error = node.simulation_error
    return None if error is None else f'simulation stopped: {error!r}'


if __name__ == '__main__':
    sys.exit(main())
