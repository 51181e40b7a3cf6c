"""The policy node's parameters: their declarations and their values. Plain Python, no ROS."""

from dataclasses import dataclass

from ur_rg2_common.parameters import ParameterSpec

from ur_rg2_learning.tasks import BALL_RADIUS

PARAMETERS = (
    ParameterSpec('policy_dir', 'reach', 'The policy to run: a directory written by '
                  "train_policy --out, or a policy shipped with the package: 'reach', "
                  "'pick', 'pick_cloned' or 'pick_demos' (empty: 'reach')", read_only=True),
    ParameterSpec('ball_radius', BALL_RADIUS, "The ball's radius, m: Reach's goal is its top, "
                  "Pick's success its bottom 10 cm above the floor", bounds=(0.005, 0.2)),
    ParameterSpec('ball_timeout', 1.0, 'policy/run needs a ball/position received at most '
                  'this long ago, s', bounds=(0.05, 60.0)),
)


@dataclass(frozen=True)
class PolicySettings:
    """The policy node's parameter values (rclpy has checked their types and bounds)."""

    policy_dir: str  # a directory, or the name of a shipped policy
    ball_radius: float
    ball_timeout: float

    @classmethod
    def from_values(cls, values: dict) -> 'PolicySettings':
        """Return the settings of raw parameter values, by name."""
        return cls(policy_dir=values['policy_dir'] or 'reach',
                   ball_radius=float(values['ball_radius']),
                   ball_timeout=float(values['ball_timeout']))
