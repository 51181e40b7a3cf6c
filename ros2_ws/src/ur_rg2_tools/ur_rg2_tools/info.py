"""``info``: what ``ros2 bag info`` prints about a recording, from the MCAP file alone.

``ros2 run ur_rg2_tools info FILE`` reads the file's summary section (statistics, channels,
schemas, chunk indexes); a file without one (a recorder killed before the end) is read through
instead, up to its first incomplete record. No ROS needed.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import sys
import time
from typing import BinaryIO, NamedTuple

from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import breakup_chunk

from ur_rg2_tools.bag import READ_ERRORS, RecordingError, check_magic, readable_records

STORAGE_ID = 'mcap'
_INDENT = 19  # the width of ros2 bag info's field names, 'Topic information: '


class TopicCount(NamedTuple):
    """One topic of a recording and how many of its messages the file holds."""

    name: str
    type: str
    count: int
    serialization_format: str


class BagInfo(NamedTuple):
    """What ``info`` prints about a file."""

    path: Path
    size: int
    messages: int
    start_ns: int
    end_ns: int
    topics: list[TopicCount]
    compression: list[str]  # of the chunks, 'none' for uncompressed ones
    cut_short: str | None  # why reading stopped before the end of a file without a summary


def _topics(channels: dict[int, Channel], schemas: dict[int, Schema],
            counts: dict[int, int]) -> list[TopicCount]:
    return sorted((TopicCount(c.topic, schemas[c.schema_id].name if c.schema_id in schemas
                              else '', counts.get(c.id, 0), c.message_encoding)
                   for c in channels.values()), key=lambda topic: topic.name)


def _compression(names: set[str]) -> list[str]:
    return sorted(name or 'none' for name in names)


def _from_summary(stream: BinaryIO, path: Path, size: int) -> BagInfo | None:
    try:
        summary = SeekingReader(stream).get_summary()
    except READ_ERRORS:
        return None
    if summary is None or summary.statistics is None:
        return None
    statistics = summary.statistics
    return BagInfo(path, size, statistics.message_count, statistics.message_start_time,
                   statistics.message_end_time,
                   _topics(summary.channels, summary.schemas,
                           statistics.channel_message_counts),
                   _compression({index.compression for index in summary.chunk_indexes}), None)


def _by_reading(stream: BinaryIO, path: Path, size: int) -> BagInfo:
    channels: dict[int, Channel] = {}
    schemas: dict[int, Schema] = {}
    counts: dict[int, int] = {}
    compression: set[str] = set()
    start, end = None, None  # the earliest and the latest log time
    records = readable_records(stream, emit_chunks=True)
    while True:
        try:
            record = next(records)
            inner = breakup_chunk(record) if isinstance(record, Chunk) else [record]
        except StopIteration as stop:
            error = stop.value
            break
        except READ_ERRORS as error_in_chunk:  # a chunk whole on disk but damaged
            error = f'{type(error_in_chunk).__name__}: {error_in_chunk}'
            break
        if isinstance(record, Chunk):
            compression.add(record.compression)
        for item in inner:
            if isinstance(item, Schema):
                schemas[item.id] = item
            elif isinstance(item, Channel):
                channels[item.id] = item
            elif isinstance(item, Message):
                counts[item.channel_id] = counts.get(item.channel_id, 0) + 1
                start = min(start if start is not None else item.log_time, item.log_time)
                end = max(end or 0, item.log_time)
    return BagInfo(path, size, sum(counts.values()), start or 0, end or 0,
                   _topics(channels, schemas, counts), _compression(compression), error)


def read_info(path: str | os.PathLike) -> BagInfo:
    """Return what ``info`` prints about ``path``; RecordingError when it is no MCAP file."""
    path = Path(path)
    try:
        stream = open(path, 'rb')  # noqa: SIM115 - closed below
        size = os.fstat(stream.fileno()).st_size
    except OSError as error:
        raise RecordingError(f'cannot open {path}: {error.strerror}') from None
    with stream:
        check_magic(stream, path)
        found = _from_summary(stream, path, size)
        if found is not None:
            return found
        stream.seek(0)
        return _by_reading(stream, path, size)


def format_size(size: int) -> str:
    """Return ``size`` bytes as ``ros2 bag info`` shows it: ``123 B``, ``20.1 MiB``."""
    value, unit = float(size), 'B'
    for unit in ('B', 'KiB', 'MiB', 'GiB', 'TiB'):
        if value < 1024 or unit == 'TiB':
            break
        value /= 1024
    return f'{value:.0f} {unit}' if unit == 'B' else f'{value:.1f} {unit}'


def format_time(nanoseconds: int) -> str:
    """Return a time as ``ros2 bag info`` shows it: local date and time, then seconds."""
    seconds, fraction = divmod(nanoseconds, 10 ** 9)
    local = time.strftime('%b %e %Y %H:%M:%S', time.localtime(seconds))
    return f'{local}.{fraction:09d} ({seconds}.{fraction:09d})'


def format_info(info: BagInfo) -> str:
    """Return the lines ``ros2 bag info`` prints for ``info``, plus the chunks' compression."""
    duration = max(info.end_ns - info.start_ns, 0)
    topics = [f'Topic: {t.name} | Type: {t.type} | Count: {t.count} | '
              f'Serialization Format: {t.serialization_format}' for t in info.topics]
    lines = [
        f"{'Files:':<{_INDENT}}{info.path.name}",
        f"{'Bag size:':<{_INDENT}}{format_size(info.size)}",
        f"{'Storage id:':<{_INDENT}}{STORAGE_ID}",
        f"{'Compression:':<{_INDENT}}{', '.join(info.compression) or 'none (no chunks)'}",
        f"{'Duration:':<{_INDENT}}{duration // 10 ** 9}.{duration % 10 ** 9:09d}s",
        f"{'Start:':<{_INDENT}}{format_time(info.start_ns)}",
        f"{'End:':<{_INDENT}}{format_time(info.end_ns)}",
        f"{'Messages:':<{_INDENT}}{info.messages}",
        f"{'Topic information:':<{_INDENT}}{topics[0] if topics else ''}",
        *(' ' * _INDENT + topic for topic in topics[1:]),
    ]
    if info.cut_short is not None:
        lines.append(f"{'Cut short:':<{_INDENT}}no summary section, read up to an incomplete "
                     f'record ({info.cut_short}); `ros2 run ur_rg2_tools recover '
                     f'{info.path}` writes a complete file')
    return '\n'.join(lines)


def main(args: list[str] | None = None) -> int:
    """Print FILE's information; exit 1 when FILE is missing or no MCAP file."""
    parser = argparse.ArgumentParser(prog='info', description=__doc__.splitlines()[0])
    parser.add_argument('file', metavar='FILE', help='an MCAP recording')
    options = parser.parse_args(args)
    try:
        info = read_info(options.file)
    except RecordingError as error:
        print(f'info: {error}', file=sys.stderr)
        return 1
    print(format_info(info))
    return 0


if __name__ == '__main__':
    sys.exit(main())
