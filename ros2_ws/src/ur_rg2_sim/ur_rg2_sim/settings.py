"""The sim's parameters: their declarations and their validated values. Plain Python, no ROS."""

from collections.abc import Sequence
from dataclasses import dataclass

from ur_rg2_common.contract import ARM_JOINTS
from ur_rg2_common.parameters import ParameterSpec
from ur_rg2_common.scene_objects import SceneObject

from ur_rg2_sim.camera import RENDERERS, CameraConfig
from ur_rg2_sim.commands import CommandError, finite_vector, in_range
from ur_rg2_sim.robot_model import ROBOT_MODELS
from ur_rg2_sim.simulation import Schedule
from ur_rg2_sim.world import DEFAULT_BALL_POSITION

PARAMETERS = (
    ParameterSpec('robot_model', 'ur5', f"UR arm model: {' or '.join(ROBOT_MODELS)}",
                  read_only=True),
    ParameterSpec('gui', False, 'Open the pybullet GUI window (needs a display)', read_only=True),
    ParameterSpec('real_time_factor', 1.0, 'Simulation speed relative to the wall clock; 0 = as '
                  'fast as possible'),
    ParameterSpec('physics_rate', 240.0, 'Physics steps per second of simulation time',
                  read_only=True),
    ParameterSpec('joint_state_rate', 100.0, 'joint_states rate, Hz of simulation time'),
    ParameterSpec('camera_rate', 30.0, 'Camera frame rate, Hz of simulation time; 0 turns the '
                  'camera off'),
    ParameterSpec('renderer', 'auto', f"Camera renderer: {', '.join(RENDERERS)} (auto: OpenGL on "
                  "EGL where it loads, else pybullet's TinyRenderer)", read_only=True),
    ParameterSpec('camera_width', 640, 'Image width, pixels'),
    ParameterSpec('camera_height', 480, 'Image height, pixels'),
    ParameterSpec('camera_hfov', 57.0, 'Horizontal field of view, degrees (Kinect v1: 57)'),
    ParameterSpec('camera_position', list(CameraConfig.position), 'Camera position [x, y, z], '
                  'world frame, m'),
    ParameterSpec('camera_look_at', list(CameraConfig.look_at), 'Point the camera looks at '
                  '[x, y, z], world frame, m'),
    ParameterSpec('ball_position', list(DEFAULT_BALL_POSITION), 'Ball centre [x, y, z], world '
                  'frame, m; setting it moves the ball there at rest'),
    ParameterSpec('ball_radius', 0.03, 'Ball radius, m', read_only=True),
    ParameterSpec('ball_color', [1.0, 0.0, 0.0, 1.0], 'Ball colour [r, g, b, a], 0-1'),
    ParameterSpec('floor_color', [c / 255 for c in CameraConfig.floor_colors[0]], 'Floor colour '
                  '[r, g, b], 0-1 (its tiles alternate with a darker shade)'),
    ParameterSpec('light_direction', list(CameraConfig.light_direction), 'Direction toward the '
                  'light [x, y, z], world frame (brightness and shading of everything the camera '
                  'sees)'),
    ParameterSpec('scene_objects', '', 'Static objects on the floor that are not balls (cubes, '
                  'boxes, flat discs; e.g. for a detector data set), separated by ";": '
                  '"box|disc x y yaw size1 size2 size3 r g b" (world m, rad; box: half extents; '
                  'disc: radius, unused, half height; colour 0-1); setting it replaces the '
                  'previous ones'),
    ParameterSpec('home_position', [0.0] * len(ARM_JOINTS), 'Arm home pose for reset, rad, joint '
                  'order of joint_states'),
    ParameterSpec('frame_prefix', '', 'Prepended to every frame id the sim publishes (several '
                  'robots on one graph)', read_only=True),
)
# Wall time a service waits beyond the simulation time it allows, for a loaded machine.
_WALL_MARGIN = 5.0  # s


@dataclass(frozen=True)
class SimSettings:
    """Validated parameter values."""

    robot_model: str
    gui: bool
    real_time_factor: float
    physics_rate: float
    joint_state_rate: float
    camera_rate: float
    renderer: str
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
        if values['renderer'] not in RENDERERS:
            raise CommandError(f"renderer must be {', '.join(RENDERERS)}, "
                               f"got {values['renderer']!r}")
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
            renderer=values['renderer'],
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

    def wall_timeout(self, sim_seconds: float) -> float:
        """Return the wall time that ``sim_seconds`` of simulation take, with a margin."""
        # With factor 0 the simulation runs faster than real time anyway.
        factor = self.real_time_factor
        return (sim_seconds / factor if factor > 0 else sim_seconds) + _WALL_MARGIN


def _shade(rgb: Sequence[float], scale: float) -> tuple[int, int, int]:
    return tuple(round(c * scale) for c in rgb)
