"""The view3d node's parameters: their declarations and their values. Plain Python, no ROS."""

from dataclasses import dataclass

from ur_rg2_common.parameters import ParameterSpec

VIEW3D_PARAMETERS = (
    ParameterSpec('address', '127.0.0.1', 'Address to serve on. Loopback by default: the page '
                  'has no authentication, so only set another address on a trusted network.',
                  read_only=True),
    ParameterSpec('port', 8081, 'TCP port to serve on (0: any free port, logged at start-up).',
                  read_only=True, bounds=(0, 65535)),
    ParameterSpec('cloud_step', 8, 'Point cloud: every Nth pixel of the depth image in each '
                  'direction (8: 80x60 points of a 640x480 image).', bounds=(1, 64)),
)


@dataclass(frozen=True)
class View3dSettings:
    """The view3d node's parameter values (rclpy has checked their types and bounds)."""

    address: str
    port: int
    cloud_step: int  # every Nth depth pixel in each direction

    @classmethod
    def from_values(cls, values: dict) -> 'View3dSettings':
        """Return the settings of raw parameter values, by name."""
        return cls(values['address'], values['port'], values['cloud_step'])
