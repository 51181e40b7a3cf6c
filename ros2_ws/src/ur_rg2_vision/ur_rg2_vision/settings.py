"""The vision and viewer nodes' parameters: declarations and validated values. No ROS."""

from dataclasses import dataclass
import os

from ur_rg2_common.parameters import ParameterSpec

from ur_rg2_vision.detector import DEFAULT_MIN_RADIUS_PX, RED, HsvRange

PARAMETERS = (
    ParameterSpec('frames_dir', 'frames', 'Directory for saved frames (created when needed); '
                  'a relative path is relative to the directory the node was started from.'),
    ParameterSpec('save_every_n', 0, 'Save every Nth colour frame (and its depth) '
                  'automatically; 0: off.', bounds=(0, 1_000_000)),
    ParameterSpec('hsv_lower', list(RED.lower), 'Ball colour, lower HSV bound [H 0-179, S 0-255, '
                  'V 0-255] (OpenCV scale). A lower hue above the upper hue wraps around 0, as '
                  'red does.'),
    ParameterSpec('hsv_upper', list(RED.upper), 'Ball colour, upper HSV bound [H, S, V]; see '
                  'hsv_lower.'),
    ParameterSpec('min_radius_px', DEFAULT_MIN_RADIUS_PX, 'Smallest ball radius in pixels that '
                  'counts as a ball.', bounds=(1.0, 1000.0)),
    ParameterSpec('ball_radius', 0.0, 'Ball radius in metres; 0: measure it in every frame from '
                  'the depth and the outline. A radius given is assumed: balls of another size '
                  'are not found.', bounds=(0.0, 10.0)),
    ParameterSpec('detector', 'color', 'How balls are found in the colour image: "color" (the '
                  'HSV range above, round blobs) or "learned" (a trained network, ONNX, any '
                  'colour); the depth then gives the 3D centre either way.', read_only=True),
    ParameterSpec('model_dir', '', 'detector "learned": a directory written by train_detector '
                  '(model.onnx, detector.json); empty: the model shipped with the package.',
                  read_only=True),
)
DETECTORS = ('color', 'learned')


@dataclass(frozen=True)
class VisionSettings:
    """Validated parameter values."""

    frames_dir: str  # absolute: logs and save_frame answers say where the files really are
    save_every_n: int
    color: HsvRange  # hsv_lower, hsv_upper
    min_radius_px: float
    ball_radius: float
    detector: str
    model_dir: str

    @classmethod
    def from_values(cls, values: dict) -> 'VisionSettings':
        """Validate raw parameter values; raise ValueError naming the first bad one."""
        if values['detector'] not in DETECTORS:
            raise ValueError(f"detector must be {' or '.join(DETECTORS)}, got "
                             f"{values['detector']!r}")
        if not values['ball_radius'] >= 0:
            raise ValueError(f'ball_radius must be 0 (measure) or positive, got '
                             f'{values["ball_radius"]}')
        return cls(
            frames_dir=os.path.abspath(values['frames_dir']),
            save_every_n=values['save_every_n'],
            color=HsvRange(tuple(int(x) for x in values['hsv_lower']),
                           tuple(int(x) for x in values['hsv_upper'])),
            min_radius_px=float(values['min_radius_px']),
            ball_radius=float(values['ball_radius']),
            detector=values['detector'],
            model_dir=values['model_dir'],
        )


VIEWER_PARAMETERS = (
    ParameterSpec('address', '127.0.0.1', 'Address to serve on. Loopback by default: the page '
                  'has no authentication, so only set another address on a trusted network.',
                  read_only=True),
    ParameterSpec('port', 8080, 'TCP port to serve on (0: any free port, logged at start-up).',
                  read_only=True, bounds=(0, 65535)),
    ParameterSpec('image_topic', 'ball/image', 'Colour image topic to stream: the annotated '
                  'ball/image, or camera/color/image_raw to watch the raw camera without vision.',
                  read_only=True),
    ParameterSpec('jpeg_quality', 80, 'JPEG quality of the stream and snapshots, 1-100.',
                  read_only=True, bounds=(1, 100)),
)


@dataclass(frozen=True)
class ViewerSettings:
    """The viewer node's parameter values (rclpy has checked their types and bounds)."""

    address: str
    port: int
    image_topic: str
    jpeg_quality: int

    @classmethod
    def from_values(cls, values: dict) -> 'ViewerSettings':
        """Return the settings of raw parameter values, by name."""
        return cls(values['address'], values['port'], values['image_topic'],
                   values['jpeg_quality'])
