"""The rg2_adapter node's parameters: their declarations and their values. Plain Python."""

from dataclasses import dataclass

from ur_rg2_common.parameters import ParameterSpec

PARAMETERS = (
    ParameterSpec('onrobot_action', 'onrobot/gripper_controller/gripper_cmd', "OnRobot driver's "
                  'ParallelGripperCommand action', read_only=True),
    ParameterSpec('onrobot_joint_states', 'onrobot/joint_states', "OnRobot driver's joint "
                  'states (its stroke joint)', read_only=True),
    ParameterSpec('stroke_joint', 'grip_stroke', "OnRobot driver's joint: the opening "
                  'between the pads, m', read_only=True),
    ParameterSpec('goal_timeout', 10.0, 'A driver goal not ended after this long is cancelled '
                  'and fails, s', bounds=(1.0, 60.0)),
)


@dataclass(frozen=True)
class AdapterSettings:
    """The rg2_adapter node's parameter values (rclpy has checked their types and bounds)."""

    onrobot_action: str
    onrobot_joint_states: str
    stroke_joint: str
    goal_timeout: float  # s

    @classmethod
    def from_values(cls, values: dict) -> 'AdapterSettings':
        """Return the settings of raw parameter values, by name."""
        return cls(values['onrobot_action'], values['onrobot_joint_states'],
                   values['stroke_joint'], float(values['goal_timeout']))
