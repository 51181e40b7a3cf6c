"""MCAP files of the ROS 2 profile: writing serialized messages, opening, recovering.

What rosbag2's MCAP storage writes, so that ``ros2 bag info|play``, Foxglove, Lichtblick and
Rerun read our files: profile ``ros2``, CDR messages, one ``ros2msg`` schema per type
(from :mod:`ur_rg2_tools.msgdefs`), channel metadata ``offered_qos_profiles`` (rosbag2's YAML,
metadata version 9: policies as strings) and ``topic_type_hash``. Messages go into chunks
(compressed one by one): a recorder killed mid-run leaves every chunk written before, which
:func:`recover` turns into a complete file, as the mcap CLI's ``mcap recover`` does.

No ROS imports: the nodes hand in bytes, names and QoS profiles.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
import os
from pathlib import Path
import struct
from typing import Any, BinaryIO, NamedTuple

from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import MCAP0_MAGIC, CompressionType, Writer
import yaml

PROFILE = 'ros2'
LIBRARY = 'ur_rg2_tools record (mcap python)'
COMPRESSION = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
               'none': CompressionType.NONE}
CHUNK_SIZE = 1024 * 1024  # bytes of messages per chunk: what a killed recorder can lose
_INFINITE_NS = 2 ** 63 - 1  # RMW_DURATION_INFINITE
# What a truncated or damaged file raises while its records are read (zstd and lz4 raise
# their own errors, subclasses of these, for a damaged chunk).
READ_ERRORS = (McapError, struct.error, ValueError, EOFError, RuntimeError, OSError)


class RecordingError(Exception):
    """A file that cannot be read as a recording, with the reason and what to do."""


def check_magic(stream: BinaryIO, name: str | os.PathLike) -> None:
    """Raise RecordingError unless ``stream`` starts with MCAP's magic bytes; rewind it.

    A file without them is something else (text, another format), which ``recover`` cannot help
    with either; a file with them and a broken end is an MCAP file cut short.
    """
    magic = stream.read(len(MCAP0_MAGIC))
    stream.seek(0)
    if magic != MCAP0_MAGIC:
        raise RecordingError(f"{name} is not an MCAP file (it does not start with MCAP's magic "
                             'bytes)')


def _duration(nanoseconds: int) -> dict[str, int]:
    nanoseconds = min(int(nanoseconds), _INFINITE_NS)
    return {'sec': nanoseconds // 10 ** 9, 'nsec': nanoseconds % 10 ** 9}


def offered_qos_yaml(profiles: Iterable[Any]) -> str:
    """Return rosbag2's ``offered_qos_profiles`` YAML for rclpy QoS profiles (publishers')."""
    entries = []
    for qos in profiles:
        entries.append({
            'history': qos.history.name.lower(),
            'depth': int(qos.depth),
            'reliability': qos.reliability.name.lower(),
            'durability': qos.durability.name.lower(),
            'deadline': _duration(qos.deadline.nanoseconds),
            'lifespan': _duration(qos.lifespan.nanoseconds),
            'liveliness': qos.liveliness.name.lower(),
            'liveliness_lease_duration': _duration(qos.liveliness_lease_duration.nanoseconds),
            'avoid_ros_namespace_conventions': bool(qos.avoid_ros_namespace_conventions),
        })
    return yaml.safe_dump(entries, sort_keys=False) if entries else ''


def recorded_qos(channel: Channel) -> dict[str, Any]:
    """Return the first offered profile recorded for ``channel`` (policy names), or {}."""
    try:
        profiles = yaml.safe_load(channel.metadata.get('offered_qos_profiles', '') or '[]')
        return dict(profiles[0]) if profiles else {}
    except (yaml.YAMLError, TypeError, KeyError, IndexError):
        return {}


class _FileSink:
    """A file written straight through, chunk by chunk.

    mcap's Writer would buffer a raw file in memory, where a killed recorder's finished chunks
    would be lost.
    """

    def __init__(self, raw: BinaryIO) -> None:
        self._raw = raw

    def write(self, data: bytes) -> int:
        view = memoryview(data)
        while view:
            view = view[self._raw.write(view):]
        return len(data)

    def tell(self) -> int:
        return self._raw.tell()

    def flush(self) -> None:
        """Nothing is held back."""


class BagWriter:
    """Writes serialized ROS 2 messages to an MCAP file (one thread at a time)."""

    def __init__(self, output: str | os.PathLike | BinaryIO, compression: str = 'zstd',
                 chunk_size: int = CHUNK_SIZE) -> None:
        self._file = None
        if isinstance(output, (str, os.PathLike)):
            # 'x': never overwrite a recording; unbuffered, so that a chunk is handed to the
            # kernel whole as soon as it is written and survives the recorder being killed.
            self._file = open(output, 'xb', buffering=0)  # noqa: SIM115 - closed in finish
            output = _FileSink(self._file)
        self._stream = output
        self._writer = Writer(output, chunk_size=chunk_size,
                              compression=COMPRESSION[compression])
        self._writer.start(profile=PROFILE, library=LIBRARY)
        self._schemas: dict[str, int] = {}
        self.messages = 0
        self.data_bytes = 0
        self._finished = False

    def add_topic(self, topic: str, type_name: str, definition: str, offered_qos: str = '',
                  type_hash: str = '') -> int:
        """Register ``topic`` of ``type_name`` (pkg/msg/Type); return its channel id.

        ``definition`` is the type's complete ``ros2msg`` text (:func:`msgdefs.full_text`).
        """
        schema = self._schemas.get(type_name)
        if schema is None:
            schema = self._writer.register_schema(type_name, 'ros2msg', definition.encode())
            self._schemas[type_name] = schema
        metadata = {'offered_qos_profiles': offered_qos}
        if type_hash:
            metadata['topic_type_hash'] = type_hash
        return self._writer.register_channel(topic, 'cdr', schema, metadata)

    def write(self, channel: int, data: bytes, log_time: int, publish_time: int,
              sequence: int = 0) -> None:
        """Add one CDR-serialized message; times in ns since the epoch."""
        self._writer.add_message(channel, log_time, data, publish_time, sequence % 2 ** 32)
        self.messages += 1
        self.data_bytes += len(data)

    def file_bytes(self) -> int:
        """Return how many bytes went to the file so far."""
        return self._stream.tell()

    def finish(self) -> None:
        """Write the last chunk, the index and the footer, and close the file (idempotent)."""
        if self._finished:
            return
        self._finished = True
        try:
            self._writer.finish()
        finally:
            self.abandon()

    def abandon(self) -> None:
        """Close the file as it is (after a write failed): its complete chunks stay readable."""
        self._finished = True
        if self._file is not None:
            try:
                self._file.close()
            except OSError:
                pass


class Recording(NamedTuple):
    """An opened, complete recording."""

    reader: SeekingReader
    stream: BinaryIO
    channels: dict[int, Channel]
    schemas: dict[int, Schema]
    message_count: int
    start_ns: int
    end_ns: int


def open_recording(path: str | os.PathLike) -> Recording:
    """Open a complete MCAP file for reading; RecordingError with the reason otherwise."""
    try:
        stream = open(path, 'rb')  # noqa: SIM115 - the caller closes recording.stream
    except OSError as error:
        raise RecordingError(f'cannot open {path}: {error.strerror}') from None
    try:
        check_magic(stream, path)
    except RecordingError:
        stream.close()
        raise
    try:
        reader = SeekingReader(stream)
        summary = reader.get_summary()
        if summary is None or summary.statistics is None:
            raise McapError('no summary section')
    except READ_ERRORS as error:
        stream.close()
        raise RecordingError(
            f'{path} is not a complete MCAP file ({type(error).__name__}: {error}); a recorder '
            'that was killed or ran out of disk leaves its chunks readable: `ros2 run '
            f'ur_rg2_tools recover {path}` writes them to a complete file') from None
    statistics = summary.statistics
    return Recording(reader, stream, dict(summary.channels), dict(summary.schemas),
                     statistics.message_count, statistics.message_start_time,
                     statistics.message_end_time)


class Recovered(NamedTuple):
    """What :func:`recover` kept."""

    messages: int
    error: str | None  # why reading stopped before the end, None for a complete file


def readable_records(stream: BinaryIO, emit_chunks: bool = False) -> Iterator[Any]:
    """Yield the records of an MCAP stream up to its end or up to its first incomplete record.

    The messages of every complete chunk come out (the chunks themselves with
    ``emit_chunks``); a chunk cut short does not. Raises RecordingError when the stream is no
    MCAP at all, or ends before its header. The generator's return value (from ``yield
    from``) is the error that stopped it, or None.
    """
    name = getattr(stream, 'name', 'the stream')
    check_magic(stream, name)
    records = StreamReader(stream, emit_chunks=emit_chunks).records
    try:
        first = next(records)
    except READ_ERRORS as error:
        raise RecordingError(f'{name} ends within its MCAP header: nothing to read '
                             f'({type(error).__name__}: {error})'.replace(': )', ')')) from None
    yield first
    try:
        yield from records
    except READ_ERRORS as error:
        return f'{type(error).__name__}: {error}'.rstrip(': ')
    return None


def recover(source: str | os.PathLike, target: str | os.PathLike) -> Recovered:
    """Write every readable message of ``source`` (its complete chunks) to a complete ``target``.

    ``target`` appears whole or not at all (written to a temporary name, then renamed).
    """
    target = Path(target)
    partial = target.with_name(f'.{target.name}.partial')
    try:
        stream = open(source, 'rb')  # noqa: SIM115 - closed below
    except OSError as error:
        raise RecordingError(f'cannot open {source}: {error.strerror}') from None
    try:
        with open(partial, 'wb') as out:
            writer = Writer(out, compression=CompressionType.ZSTD)
            records = readable_records(stream)
            header = next(records)
            profile = header.profile if isinstance(header, Header) else PROFILE
            writer.start(profile=profile, library=LIBRARY + ' recover')
            schemas: dict[int, int] = {}
            channels: dict[int, int] = {}
            messages = 0
            while True:
                try:
                    record = next(records)
                except StopIteration as stop:
                    error = stop.value
                    break
                if isinstance(record, Schema) and record.id not in schemas:
                    schemas[record.id] = writer.register_schema(record.name, record.encoding,
                                                                record.data)
                elif isinstance(record, Channel) and record.id not in channels:
                    channels[record.id] = writer.register_channel(
                        record.topic, record.message_encoding,
                        schemas.get(record.schema_id, 0), record.metadata)
                elif isinstance(record, Message) and record.channel_id in channels:
                    writer.add_message(channels[record.channel_id], record.log_time,
                                       record.data, record.publish_time, record.sequence)
                    messages += 1
                elif isinstance(record, Metadata):
                    writer.add_metadata(record.name, record.metadata)
            writer.finish()
        os.replace(partial, target)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    finally:
        stream.close()
    return Recovered(messages, error)
