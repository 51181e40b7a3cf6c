"""The keys node's parameters: their declarations and their values. Plain Python, no ROS."""

from dataclasses import dataclass

from ur_rg2_common.parameters import ParameterSpec

from ur_rg2_teleop.keymap import MAX_STEP_DEG, MAX_STEP_MM, MIN_STEP_DEG, MIN_STEP_MM

PARAMETERS = (
    ParameterSpec('step_deg', 5.0, 'Degrees one jog key moves its joint (or, in tool mode, '
                  'turns the TCP); + and - change it in joint mode',
                  bounds=(MIN_STEP_DEG, MAX_STEP_DEG)),
    ParameterSpec('step_mm', 10.0, 'Millimetres one jog key moves the TCP in tool mode; + and - '
                  'change it in tool mode', bounds=(MIN_STEP_MM, MAX_STEP_MM)),
)


@dataclass(frozen=True)
class KeysSettings:
    """The keys node's parameter values (rclpy has checked their types and bounds)."""

    step_deg: float  # jog step, degrees
    step_mm: float  # tool-mode TCP step, millimetres

    @classmethod
    def from_values(cls, values: dict) -> 'KeysSettings':
        """Return the settings of raw parameter values, by name."""
        return cls(step_deg=float(values['step_deg']), step_mm=float(values['step_mm']))
