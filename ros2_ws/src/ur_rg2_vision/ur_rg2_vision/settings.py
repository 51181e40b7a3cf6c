"""The vision node's parameters, declared with descriptions."""

from ur_rg2_common.parameters import ParameterSpec

from ur_rg2_vision.detector import DEFAULT_MIN_RADIUS_PX, RED

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
# Parameters that change how balls are found in the next frame.
DETECTION_PARAMETERS = ('hsv_lower', 'hsv_upper', 'min_radius_px', 'ball_radius')
