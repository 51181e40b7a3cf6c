"""The motion node's parameters: their declarations and their values. Plain Python, no ROS."""

from dataclasses import dataclass

from ur_rg2_common.parameters import ParameterSpec

from ur_rg2_motion.kinematics import FLOOR_CLEARANCE, PEDESTAL_HALF_WIDTH
from ur_rg2_motion.pick import PickSettings

PARAMETERS = (
    ParameterSpec('lift_height', 0.15, 'How high pick_ball lifts the ball, m', bounds=(0.0, 0.5)),
    ParameterSpec('approach_height', 0.10, 'pick_ball comes down onto the ball from this high '
                  'above the grasp, m', bounds=(0.02, 0.4)),
    ParameterSpec('speed_scale', 0.7, "Fraction of the joints' velocity limits that TCP moves "
                  'and the pick use at most', bounds=(0.05, 1.0)),
    ParameterSpec('tcp_speed', 0.25, 'Peak TCP speed of a straight tool_command or tool_jog '
                  'move, m/s', bounds=(0.01, 1.0)),
    ParameterSpec('approach_speed', 0.25, "Peak TCP speed of the pick's descent and lift, m/s",
                  bounds=(0.01, 0.5)),
    ParameterSpec('ball_timeout', 1.0, 'pick_ball uses a ball/position received at most this '
                  'long ago, s', bounds=(0.05, 60.0)),
    ParameterSpec('floor_clearance', FLOOR_CLEARANCE, 'Height above the floor that the TCP, '
                  'finger tips, wrist and elbow keep, m', bounds=(0.0, 0.2)),
    ParameterSpec('pedestal_half_width', PEDESTAL_HALF_WIDTH, 'Half the width of the pedestal '
                  'under base_link (floor to base_link), kept out of, m; 0: none',
                  bounds=(0.0, 1.0)),
    ParameterSpec('grasp_tolerance', 0.02, "A gripper stopped within this of the ball's "
                  'diameter holds the ball, m', bounds=(0.001, 0.05)),
    ParameterSpec('tcp_offset', [0.0, 0.0, 0.0], 'The TCP (the grasp point between the pads) '
                  'from tool0, [x, y, z] in m along its axes, for a robot_description without '
                  'an rg2_tcp frame (a real UR: an RG2 on the flange is about [0, 0, 0.2]); '
                  '[0, 0, 0]: not set', read_only=True),
)


@dataclass(frozen=True)
class MotionSettings:
    """The motion node's parameter values (rclpy has checked their types and bounds)."""

    lift_height: float
    approach_height: float
    speed_scale: float
    tcp_speed: float
    approach_speed: float
    ball_timeout: float
    floor_clearance: float
    pedestal_half_width: float
    grasp_tolerance: float
    tcp_offset: tuple[float, float, float] | None  # None: not set

    @classmethod
    def from_values(cls, values: dict) -> 'MotionSettings':
        """Return the settings of raw parameter values, by name."""
        offset = tuple(float(v) for v in values['tcp_offset'])
        return cls(**{spec.name: float(values[spec.name]) for spec in PARAMETERS
                      if spec.name != 'tcp_offset'},
                   tcp_offset=offset if any(offset) else None)

    def pick(self) -> PickSettings:
        """Return the pick's share of the settings."""
        return PickSettings(self.approach_height, self.lift_height, self.speed_scale,
                            self.approach_speed, self.grasp_tolerance)
