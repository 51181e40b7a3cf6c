"""``replay``: publish an MCAP recording with its timing, as ``ros2 bag play --clock`` does.

``ros2 run ur_rg2_tools replay FILE [--rate R] [--loop] [TOPIC ...]``. Each message goes out as
the bytes it was recorded as, at its recorded (receive) time scaled by ``--rate``, with the QoS
its publishers offered (so /tf_static and robot_description are latched again). ``/clock``:
the recorded one when the recording has it (the sim's time, which every header stamp uses),
else one made from the recording's times at 100 Hz. A missing, truncated or foreign file is
one error line and exit code 1.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time

import rclpy
from rclpy.logging import get_logger
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import remove_ros_args
from rosgraph_msgs.msg import Clock
from rosidl_runtime_py.utilities import get_message
from ur_rg2_common.spin import run_node

from ur_rg2_tools.bag import READ_ERRORS, Recording, RecordingError, open_recording, recorded_qos

NODE_NAME = 'ur_rg2_replay'
CLOCK_TOPIC = '/clock'
CLOCK_PERIOD_NS = 10_000_000  # of the made-up /clock, recording time


def parse_args(argv: list[str]) -> argparse.Namespace:
    """Parse the command line (without ROS arguments)."""
    parser = argparse.ArgumentParser(
        prog='replay', description='Publish an MCAP recording with its timing and /clock.')
    parser.add_argument('file', metavar='FILE', help='the recording (.mcap)')
    parser.add_argument('topics', nargs='*', metavar='TOPIC',
                        help='replay only these topics (default: all of them)')
    parser.add_argument('--rate', type=float, default=1.0, metavar='R',
                        help='speed factor (default 1.0; 2 plays twice as fast)')
    parser.add_argument('--loop', action='store_true', help='start again at the end')
    parser.add_argument('--delay', type=float, default=1.0, metavar='S',
                        help='seconds to wait after creating the publishers, for subscribers '
                        'to connect (default 1.0)')
    options = parser.parse_args(argv)
    if not options.rate > 0:
        parser.error('--rate must be > 0')
    return options


def publisher_qos(profile: dict) -> QoSProfile:
    """Return the QoS to publish with, from a recorded offered profile (policy names or ids)."""
    def policy(enum, key, default):
        value = profile.get(key)
        try:
            return enum(value) if isinstance(value, int) else enum[str(value).upper()]
        except (KeyError, ValueError):
            return default

    depth = profile.get('depth')
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth if isinstance(depth, int) and depth > 0 else 10,
        reliability=policy(ReliabilityPolicy, 'reliability', ReliabilityPolicy.RELIABLE),
        durability=policy(DurabilityPolicy, 'durability', DurabilityPolicy.VOLATILE))


class ReplayNode(Node):
    """Publishes a recording's messages from a thread of its own, then ends the process."""

    def __init__(self, recording: Recording, options: argparse.Namespace, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self._recording = recording
        self._rate, self._loop, self._delay = options.rate, options.loop, options.delay
        recorded = {channel.topic for channel in recording.channels.values()}
        wanted = {topic if topic.startswith('/') else '/' + topic for topic in options.topics}
        unknown = wanted - recorded
        if unknown:  # as ros2 bag play: the others are replayed
            self.get_logger().warning(f'{", ".join(sorted(unknown))} not in {options.file}; it '
                                      f'has {", ".join(sorted(recorded)) or "no topics"}')
        self._topics = sorted(wanted) if wanted else None
        self._outputs = {}
        for channel_id, channel in recording.channels.items():
            if self._topics is not None and channel.topic not in self._topics:
                continue
            schema = recording.schemas.get(channel.schema_id)
            try:
                message_type = get_message(schema.name)
            except (AttributeError, ModuleNotFoundError, ValueError):
                self.get_logger().warning(f'not replaying {channel.topic}: type '
                                          f'{schema.name if schema else "?"} not installed')
                continue
            # Absolute names as recorded; remapping (--ros-args -r) still applies.
            self._outputs[channel_id] = self.create_publisher(
                message_type, channel.topic, publisher_qos(recorded_qos(channel)))
        self._clock = None
        if CLOCK_TOPIC not in recorded:
            self._clock = self.create_publisher(Clock, CLOCK_TOPIC, 10)
        self.done = False
        self.error: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._play, name='replay', daemon=True)
        self.get_logger().info(
            f'replaying {options.file}: {recording.message_count} messages over '
            f'{(recording.end_ns - recording.start_ns) / 1e9:.1f} s at rate {self._rate:g}'
            f'{", looping" if self._loop else ""} (Ctrl-C stops)')
        self._thread.start()

    def failure(self) -> str | None:
        """Return why the replay failed (run_node asks after every wait)."""
        return self.error

    def _play(self) -> None:
        if self._stop.wait(self._delay):
            return
        try:
            while not self._stop.is_set():
                count = self._play_once()
                self.get_logger().info(f'replayed {count} messages')
                if not self._loop:
                    break
        except READ_ERRORS as error:
            self.error = f'cannot read the recording: {type(error).__name__}: {error}'
            return
        self.done = True
        # The end of the replay ends the process as Ctrl-C would: exit code 0.
        rclpy.try_shutdown(context=self.context)

    def _play_once(self) -> int:
        start_ns, start = self._recording.start_ns, time.monotonic()
        last_clock = None
        count = 0
        for _, channel, message in self._recording.reader.iter_messages(
                topics=self._topics, log_time_order=True):
            due = start + (message.log_time - start_ns) / 1e9 / self._rate
            if self._stop.wait(max(0.0, due - time.monotonic())):
                break
            if self._clock is not None and (last_clock is None or message.log_time - last_clock
                                            >= CLOCK_PERIOD_NS):
                last_clock = message.log_time
                clock = Clock()
                clock.clock.sec, clock.clock.nanosec = divmod(message.log_time, 10 ** 9)
                self._clock.publish(clock)
            publisher = self._outputs.get(channel.id)
            if publisher is not None:
                publisher.publish(message.data)
                count += 1
        return count

    def destroy_node(self) -> None:
        """Stop the player thread, then the node."""
        self._stop.set()
        self._thread.join(5.0)
        self._recording.stream.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Replay a recording; exit 0 at its end or on Ctrl-C, 1 on a file that cannot be read."""
    argv = remove_ros_args(args if args is not None else sys.argv)[1:]
    options = parse_args(argv)
    try:
        recording = open_recording(options.file)
    except RecordingError as error:
        get_logger(NODE_NAME).error(str(error))
        return 1
    return run_node(lambda: ReplayNode(recording, options), args, NODE_NAME,
                    failure=ReplayNode.failure)


if __name__ == '__main__':
    sys.exit(main())
