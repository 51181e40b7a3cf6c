"""``record``: the graph's topics to an MCAP file (ROS 2 profile), as ``ros2 bag record`` does.

``ros2 run ur_rg2_tools record [-o FILE] [--all | TOPIC ...]``. Messages are taken serialized
(rclpy's ``raw=True``: the CDR bytes as they came, no decode and re-encode) and handed to a
writer thread, so the subscriptions never wait for compression or the disk; past
``--max-cache-size`` bytes waiting, a message is dropped and counted, as rosbag2 does. Each
topic is subscribed to with what its publishers offer (rosbag2's rule: reliable and transient
local when every publisher is, so /tf_static and robot_description arrive). Ctrl-C finishes
the file and exits 0; a topic that never appears, or a write that fails (disk full), ends it
with one error line and exit code 1, the file complete up to there (or its written chunks
readable by ``recover`` when even the end could not be written).
"""

from __future__ import annotations

import argparse
from functools import partial
import os
import queue
import sys
import threading
import time
from typing import Any

from rclpy.exceptions import InvalidTopicNameException
from rclpy.logging import get_logger
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import remove_ros_args
from rosidl_runtime_py.utilities import get_message
from ur_rg2_common.spin import run_node

from ur_rg2_tools.backlog import DEFAULT_MAX_BYTES, WriteBacklog
from ur_rg2_tools.bag import BagWriter, offered_qos_yaml
from ur_rg2_tools.msgdefs import DefinitionNotFoundError, full_text

NODE_NAME = 'ur_rg2_recorder'
DISCOVERY_PERIOD_S = 0.5
DEPTH = 100  # per topic: bursts wait here if the executor falls behind for a moment


def parse_args(argv: list[str]) -> argparse.Namespace:
    """Parse the command line (without ROS arguments)."""
    parser = argparse.ArgumentParser(
        prog='record', description='Record topics of the graph to an MCAP file (ROS 2 '
        'profile: ros2 bag, Foxglove, Lichtblick and Rerun read it).')
    parser.add_argument('topics', nargs='*', metavar='TOPIC',
                        help='topics to record (relative names take the node namespace)')
    parser.add_argument('-a', '--all', action='store_true',
                        help='record every topic that has a publisher, as they appear')
    parser.add_argument('-o', '--output', metavar='FILE',
                        help='file to write (default: ur_rg2_YYYY_MM_DD-HH_MM_SS.mcap); never '
                        'overwritten')
    parser.add_argument('--compression', choices=('zstd', 'lz4', 'none'), default='zstd',
                        help='compression of each chunk (default: zstd)')
    parser.add_argument('--wait', type=float, default=10.0, metavar='S',
                        help='seconds a named topic may take to appear before it is an error '
                        '(default: 10)')
    parser.add_argument('--max-cache-size', type=int, default=DEFAULT_MAX_BYTES,
                        metavar='BYTES', help='bytes of messages that may wait for the writer; '
                        f'past them messages are dropped and counted (default: {DEFAULT_MAX_BYTES}'
                        ', as rosbag2)')
    options = parser.parse_args(argv)
    if options.all == bool(options.topics):
        parser.error('give either --all or one or more topics')
    if options.max_cache_size <= 0:
        parser.error(f'--max-cache-size must be positive, not {options.max_cache_size}')
    if options.output is None:
        options.output = time.strftime('ur_rg2_%Y_%m_%d-%H_%M_%S.mcap')
    return options


def request_qos(publishers: list[Any]) -> QoSProfile:
    """Return the QoS to subscribe with to a topic with these publishers (rosbag2's rule)."""
    reliable = bool(publishers) and all(
        p.qos_profile.reliability == ReliabilityPolicy.RELIABLE for p in publishers)
    latched = bool(publishers) and all(
        p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in publishers)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=DEPTH,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


class RecorderNode(Node):
    """Subscribes to the chosen topics and writes what arrives to an MCAP file."""

    def __init__(self, options: argparse.Namespace, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self._wanted = ({self.resolve_topic_name(topic) for topic in options.topics}
                        if options.topics else None)
        self._wait = options.wait
        self.path = options.output
        self._bag = BagWriter(self.path, options.compression)  # FileExistsError: start-up error
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._backlog = WriteBacklog(options.max_cache_size)
        self._recorded: dict[str, Any] = {}
        self._failure: str | None = None
        self._write_failed = False  # the file is broken: nothing more goes to it
        self._lost = 0
        self._started = time.monotonic()
        self._progress_at = (self._started, 0)
        self._tty = sys.stderr.isatty()
        self._writer = threading.Thread(target=self._write_loop, name='mcap-writer')
        try:
            self.create_timer(DISCOVERY_PERIOD_S, self._discover)
            self.create_timer(0.5 if self._tty else 5.0, self._progress)
            what = 'every topic' if self._wanted is None else ', '.join(sorted(self._wanted))
            self.get_logger().info(f'recording {what} to {self.path} (Ctrl-C ends it)')
            self._discover()  # its topics wait in the queue for the writer
            self._writer.start()  # last: a Ctrl-C before leaves no thread behind
        except BaseException:
            self._bag.finish()  # a complete file, with nothing in it
            raise

    def failure(self) -> str | None:
        """Return why the recording cannot go on, or None (run_node asks after every wait)."""
        return self._failure

    def _discover(self) -> None:
        for topic, types in self.get_topic_names_and_types():
            if topic in self._recorded or (self._wanted is not None
                                                and topic not in self._wanted):
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                continue  # only subscribers so far: nothing to record yet
            if len(types) != 1:
                self.get_logger().warning(f'not recording {topic}: several types {types}',
                                          once=True)
                continue
            self._subscribe(topic, types[0], publishers)
        missing = (self._wanted or set()) - set(self._recorded)
        if missing and time.monotonic() - self._started > self._wait:
            self._failure = (f'unknown topic {", ".join(sorted(missing))}: no publisher on this '
                             f'graph within {self._wait:g} s (`ros2 topic list -v` shows what '
                             'is published)')

    def _subscribe(self, topic: str, type_name: str, publishers: list[Any]) -> None:
        try:
            message_type = get_message(type_name)
        except (AttributeError, ModuleNotFoundError, ValueError) as error:
            self.get_logger().warning(f'not recording {topic}: type {type_name} is not '
                                      f'installed ({error})', once=True)
            self._recorded[topic] = None
            return
        try:
            definition = full_text(type_name)
        except DefinitionNotFoundError as error:
            # rosbag2 stores no usable schema either (action feedback types have no .msg).
            self.get_logger().warning(f'not recording {topic}: no message definition '
                                      f'({error})', once=True)
            self._recorded[topic] = None
            return
        channel = len(self._recorded)  # the writer thread's key for the topic
        type_hash = str(publishers[0].topic_type_hash)
        self._queue.put(('topic', channel, topic, type_name, definition,
                         offered_qos_yaml(p.qos_profile for p in publishers), type_hash))
        self._recorded[topic] = self.create_subscription(
            message_type, topic, partial(self._on_message, channel, topic),
            request_qos(publishers),
            raw=True)
        self.get_logger().info(f'recording {topic} [{type_name}]')

    def _on_message(self, channel: int, topic: str, data: bytes, info: dict) -> None:
        if not self._backlog.take(topic, len(data)):
            self.get_logger().warning(
                f'the writer is {self._backlog.held / 1e6:.0f} MB behind: dropping messages '
                '(a larger --max-cache-size, or --compression lz4 or none, keeps up)',
                throttle_duration_sec=5.0)
            return
        self._queue.put(('message', channel, data, info['received_timestamp'],
                         info['source_timestamp'], info['publication_sequence_number']))

    def _write_loop(self) -> None:
        channels: dict[int, int] = {}  # key from _subscribe: MCAP channel id
        while (item := self._queue.get()) is not None:
            kind, channel, *rest = item
            if kind == 'message':
                self._backlog.written(len(rest[0]))
            if self._write_failed:
                self._lost += kind == 'message'
                continue
            try:
                if kind == 'topic':
                    channels[channel] = self._bag.add_topic(*rest)
                else:
                    data, received, sent, sequence = rest
                    self._bag.write(channels[channel], data, received, sent or received,
                                    sequence)
            except Exception as error:  # noqa: BLE001 - any failure ends the recording
                self._write_failed = True
                self._bag.abandon()
                self._failure = (
                    f'cannot write {self.path}: '
                    f'{getattr(error, "strerror", None) or error} after '
                    f'{self._bag.messages} messages; stopped recording. Its complete chunks '
                    f'read back with `ros2 run ur_rg2_tools recover {self.path}`')
                self._lost += kind == 'message'

    def _progress(self) -> None:
        now, bag = time.monotonic(), self._bag
        try:
            written = bag.file_bytes()
        except (OSError, ValueError):
            return
        then, before = self._progress_at
        self._progress_at = now, bag.data_bytes
        rate = (bag.data_bytes - before) / max(now - then, 1e-6) / 1e6
        line = (f'{bag.messages} messages, {bag.data_bytes / 1e6:.1f} MB '
                f'({written / 1e6:.1f} MB written), {rate:.1f} MB/s, '
                f'{len([s for s in self._recorded.values() if s])} topics')
        if self._backlog.dropped:
            line += f', {self._backlog.total_dropped} dropped'
        if self._tty:
            sys.stderr.write(f'\r{line}   ')
            sys.stderr.flush()
        else:
            self.get_logger().info(line)

    def destroy_node(self) -> None:
        """Stop taking messages, write what is queued and finish the file."""
        for subscription in self._recorded.values():
            if subscription is not None:
                self.destroy_subscription(subscription)
        self._queue.put(None)
        self._writer.join()
        if self._tty:
            sys.stderr.write('\n')
        if not self._write_failed:
            try:
                self._bag.finish()
                # Not the node's logger: after a Ctrl-C its /rosout publisher is gone.
                get_logger(f'{NODE_NAME}.file').info(
                    f'wrote {self.path}: {self._bag.messages} messages, '
                    f'{self._bag.data_bytes / 1e6:.1f} MB of messages in '
                    f'{os.path.getsize(self.path) / 1e6:.1f} MB, '
                    f'{time.monotonic() - self._started:.1f} s')
            except OSError as error:
                self._bag.abandon()
                get_logger(f'{NODE_NAME}.file').error(
                    f'cannot finish {self.path}: {error.strerror or error}; its complete '
                    f'chunks read back with `ros2 run ur_rg2_tools recover {self.path}`')
        elif self._lost:
            get_logger(f'{NODE_NAME}.file').error(f'{self._lost} messages not written')
        if self._backlog.dropped:
            get_logger(f'{NODE_NAME}.file').warning(
                f'dropped {self._backlog.summary()} messages: the writer fell behind')
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Record until Ctrl-C; exit 1 on an unknown topic or a failed write."""
    argv = remove_ros_args(args if args is not None else sys.argv)[1:]
    options = parse_args(argv)
    return run_node(lambda: RecorderNode(options), args, NODE_NAME,
                    startup_errors=(OSError, InvalidTopicNameException),
                    failure=RecorderNode.failure)


if __name__ == '__main__':
    sys.exit(main())
