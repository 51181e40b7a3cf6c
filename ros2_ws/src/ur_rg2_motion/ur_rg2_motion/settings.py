"""The motion node's parameters, declared with descriptions, and the pick's share of them."""

from collections.abc import Callable

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


def pick_settings(value: Callable[[str], object]) -> PickSettings:
    """Return the pick's settings from the parameter values ``value(name)`` gives."""
    return PickSettings(value('approach_height'), value('lift_height'), value('speed_scale'),
                        value('approach_speed'), value('grasp_tolerance'))
