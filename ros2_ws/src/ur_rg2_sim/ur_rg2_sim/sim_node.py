"""ROS 2 node ``ur_rg2_sim``: wires the pybullet simulation to topics, services, parameters."""

import os
import sys
from typing import Optional

from builtin_interfaces.msg import Time
import cv2
import rclpy
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, JointState
from std_srvs.srv import Trigger
from ur_rg2_common.contract import ARM_JOINTS, IMAGE_QOS
from ur_rg2_common.parameters import declare_parameters, follow_settings
from ur_rg2_common.spin import run_node

from ur_rg2_sim.camera import Camera, Frame, RendererError
from ur_rg2_sim.commands import CommandError, joint_targets
from ur_rg2_sim.controllers import Controllers
from ur_rg2_sim.frame_publisher import FramePublisher
from ur_rg2_sim.frames import OPTICAL_FRAME, load_frame_tree, robot_description
from ur_rg2_sim.outputs import (
    camera_images,
    camera_info,
    degrees_list,
    gripper_outcome,
    joint_state,
    stamp,
)
from ur_rg2_sim.planning import CollisionModel
from ur_rg2_sim.render_thread import DropWatch
from ur_rg2_sim.robot_model import RobotModelError
from ur_rg2_sim.safety import Homing, ProtectiveStop, no_way_home_message, protective_stop_message
from ur_rg2_sim.serialized import SerializedPublisher
from ur_rg2_sim.settings import PARAMETERS, SimSettings
from ur_rg2_sim.simulation import NS, SimulationLoop, SimulationUnavailableError, answer
from ur_rg2_sim.world import Contact, SimWorld, WorldConfig

# Gripper and reset services give up after this much simulation time (the contract's 5 s).
SERVICE_TIMEOUT = 5.0
# The fingers count as stopped once they have not moved for this long.
GRIPPER_SETTLE_TIME = 0.1


class SimNode(Node):
    """Simulated UR arm with an RG2 gripper and an RGB-D camera, per the INTERFACES contract."""

    def __init__(self, **kwargs) -> None:
        super().__init__('ur_rg2_sim', **kwargs)
        self.settings = SimSettings.from_values(declare_parameters(self, PARAMETERS))
        s = self.settings
        gui = s.gui and bool(os.environ.get('DISPLAY') or os.environ.get('WAYLAND_DISPLAY'))
        if s.gui and not gui:
            self.get_logger().warning('gui requested but there is no display: running headless')
        self._world = SimWorld(WorldConfig(
            robot_model=s.robot_model, physics_rate=s.physics_rate,
            ball_position=s.ball_position, ball_radius=s.ball_radius, ball_color=s.ball_color,
            home_position=s.home_position, gui=gui))

        # At real-time factor 0 these run thousands of times a second: serialized bytes.
        self._clock_stream = SerializedPublisher(
            self, Clock, '/clock', 10,
            lambda _, words: Clock(clock=Time(sec=int(words[0]), nanosec=int(words[1]))), 0, 2)
        self._joint_stream = SerializedPublisher(
            self, JointState, 'joint_states', 10,
            lambda doubles, words: joint_state(self._world.joint_names, doubles, words),
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
        self._frames.publish_static(stamp(0), s.camera_position, s.camera_look_at)

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
        follow_settings(self, PARAMETERS, SimSettings.from_values, self._apply_settings)

        self._drops = DropWatch()
        camera = self._make_camera(s)
        if camera is not None:
            self.get_logger().info(f'camera rendered by {camera.renderer.reason}')
        self._sim = SimulationLoop(self._world, self, s.schedule(), camera)
        self._controllers = Controllers(self, self._sim)
        # Reset's planner: a pybullet client of its own, made now, not at a first blocked reset.
        self._reset_model = CollisionModel(s.robot_model)
        # Reset's way home; a trajectory started since ends it (the others: _command_arm).
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
        if self._clock_stream.subscribers:  # else not even the stamp: thousands a second
            self._clock_stream.publish((), divmod(stamp_ns, NS))

    def joint_states(self, stamp_ns: int, world: SimWorld) -> None:
        """Publish ``joint_states``, /tf and ``ball/true_pose`` of ``world`` now."""
        if not (self._joint_stream.subscribers or self._frames.subscribed):
            return  # nothing to sample for
        sample = world.joint_states()
        self._joint_stream.publish((*sample.positions, *sample.velocities, *sample.efforts),
                                   divmod(stamp_ns, NS))
        if self._frames.subscribed:
            self._frames.publish(stamp_ns, sample.positions, world.body_pose(world.ball))

    def frame_dropped(self, stamp_ns: int, dropped: int) -> None:
        """Say that rendering cannot keep up: at the first drop, and once if it lasts."""
        if dropped == 1:
            self.get_logger().info(
                f'camera frame at {stamp_ns / 1e9:.3f} s dropped: the last frame was still being '
                'drawn. Physics and joint_states keep their rates; the count is in the summary '
                'at exit')
        if self._drops.dropped(stamp_ns, self.settings.camera_rate):
            self.get_logger().warning(
                f'the camera drops half its frames or more ({dropped} so far): this machine '
                'cannot render at camera_rate; lower camera_rate or the image size')

    def frame(self, stamp_ns: int, camera: Camera, frame: Frame) -> None:
        """Publish colour, depth and their camera_info with one header."""
        color, depth = camera_images(frame, stamp_ns, self._color_frame)
        info = camera_info(camera, color.header)
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
        self.get_logger().warning(no_way_home_message(held))

    def _on_protective_stop(self, contact: Contact, held: dict[str, float], new: bool) -> None:
        """Report a stop: abort the running trajectory, tell homing, warn once (sim thread)."""
        self._homing.blocked()
        message = protective_stop_message(contact, held)
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
        timeout = self.settings.wall_timeout(SERVICE_TIMEOUT)
        try:
            stopped = answer(self._sim.wait_until(action, SimWorld.gripper_stopped,
                                                  SERVICE_TIMEOUT, hold_s=GRIPPER_SETTLE_TIME),
                             timeout)
            state = answer(self._sim.call(lambda world: (
                world.gripper_target, world.gripper_opening(), world.gripper_holds_object())),
                timeout)
        except SimulationUnavailableError as error:
            response.success, response.message = False, str(error)
            return response
        response.success = stopped
        response.message = (gripper_outcome(*state) if stopped else
                             'the fingers did not stop within 5 s of simulation time')
        return response

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        home = dict(zip(ARM_JOINTS, self.settings.home_position))
        try:
            applied = answer(
                self._command_arm('reset', lambda world: self._homing.start(world, home)),
                self.settings.wall_timeout(SERVICE_TIMEOUT))
        except SimulationUnavailableError as error:
            response.success, response.message = False, str(error)
            return response
        response.success = True
        response.message = f'arm going home: {degrees_list(applied.values())} deg'
        return response

    # -- parameters ---------------------------------------------------------------------------

    def _apply_settings(self, settings: SimSettings) -> None:
        """Bring the world, the camera and /tf_static in line with settings set at run time."""
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
                stamp(self._sim.sim_time_ns), settings.camera_position, settings.camera_look_at))

    def _make_camera(self, settings: SimSettings) -> Optional[Camera]:
        if settings.camera_rate <= 0:
            return None
        return Camera(self._world, settings.camera_config(), settings.renderer)


def main(args: Optional[list[str]] = None) -> int:
    """Run the simulator node until Ctrl-C or SIGTERM."""
    cv2.setNumThreads(1)  # the camera's conversions are too small for OpenCV's worker threads
    return run_node(SimNode, args, 'ur_rg2_sim',
                    startup_errors=(CommandError, RobotModelError, RendererError,
                                    ParameterException),
                    on_startup_error=_invalid_parameter, failure=_simulation_failure)


def _invalid_parameter(error: Exception) -> int:
    rclpy.logging.get_logger('ur_rg2_sim').fatal(f'invalid parameter: {error}')
    return 2


def _simulation_failure(node: SimNode) -> Optional[str]:
    error = node.simulation_error
    return None if error is None else f'simulation stopped: {error!r}'


if __name__ == '__main__':
    sys.exit(main())
