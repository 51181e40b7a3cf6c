"""What the sim node publishes and answers, built from the simulation's values."""

from array import array
from collections.abc import Sequence
import math
import sys

from builtin_interfaces.msg import Time
from sensor_msgs.msg import CameraInfo, Image, JointState
from std_msgs.msg import Header

from ur_rg2_sim.camera import Camera, Frame
from ur_rg2_sim.simulation import NS


def stamp(stamp_ns: int) -> Time:
    """Return a builtin_interfaces/Time of ``stamp_ns`` nanoseconds."""
    return Time(sec=stamp_ns // NS, nanosec=stamp_ns % NS)


def joint_state(names: Sequence[str], doubles, words) -> JointState:
    """Return a JointState of positions, velocities, efforts (``doubles``) and a stamp."""
    count = len(names)
    return JointState(header=Header(stamp=Time(sec=int(words[0]), nanosec=int(words[1]))),
                      name=list(names), position=array('d', doubles[:count]),
                      velocity=array('d', doubles[count:2 * count]),
                      effort=array('d', doubles[2 * count:]))


def camera_images(frame: Frame, stamp_ns: int, frame_id: str) -> tuple[Image, Image]:
    """Return the colour (rgb8) and depth (32FC1, m) images of a camera frame, one header."""
    height, width = frame.depth.shape
    color = Image(height=height, width=width, encoding='rgb8', step=width * 3)
    color.header.stamp = stamp(stamp_ns)
    color.header.frame_id = frame_id
    color.data = frame.rgb.tobytes()
    depth = Image(header=color.header, height=height, width=width, encoding='32FC1',
                  is_bigendian=sys.byteorder == 'big', step=width * 4)
    depth.data = frame.depth.tobytes()
    return color, depth


def camera_info(camera: Camera, header: Header) -> CameraInfo:
    """Return the CameraInfo of ``camera``: pinhole, no distortion."""
    k = camera.k
    info = CameraInfo(header=header, height=camera.config.height, width=camera.config.width,
                      distortion_model='plumb_bob')
    info.d = [0.0] * 5
    info.k = k.flatten().tolist()
    info.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    info.p = [k[0, 0], 0.0, k[0, 2], 0.0, 0.0, k[1, 1], k[1, 2], 0.0, 0.0, 0.0, 1.0, 0.0]
    return info


def degrees_list(radians: Sequence[float]) -> str:
    """Return angles in radians as degrees for people, e.g. ``[0, -90, 12.5]``."""
    # + 0.0 turns a rounded -0.0 into 0.
    return '[' + ', '.join(f'{round(math.degrees(a), 1) + 0.0:g}' for a in radians) + ']'


def gripper_outcome(target: float, opening: float, holds: bool) -> str:
    """Say how a gripper/open or gripper/close call ended, from the fingers' state."""
    if target > 0:
        return f'opened: {opening * 1000:.1f} mm between the fingers'
    if holds:
        return f'grasped an object: fingers stopped at {opening * 1000:.1f} mm'
    return f'closed: nothing grasped ({opening * 1000:.1f} mm)'
