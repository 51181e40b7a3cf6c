"""``to_lerobot``: recordings of the graph to a LeRobot data set (codebase v3.0).

``ros2 run ur_rg2_tools to_lerobot RECORDING.mcap [...] -o DIR [--fps 10] [--repo-id NAME]``;
what is written is ur_rg2_tools.lerobot's. No ROS needed.
"""

from __future__ import annotations

import argparse
import sys

from ur_rg2_tools.lerobot import DEFAULT_TASK, export
from ur_rg2_tools.recording_frames import ExportError


def main(args: list[str] | None = None) -> int:
    """Export the recordings; exit 1 with one error line when one cannot be."""
    parser = argparse.ArgumentParser(
        prog='to_lerobot', description='Write recordings of the graph (MCAP) as a LeRobot data '
        'set (codebase v3.0): Parquet frames, an MP4 of the camera, meta/.')
    parser.add_argument('recordings', nargs='+', metavar='RECORDING',
                        help='MCAP files written by record (their episodes in this order)')
    parser.add_argument('-o', '--output', required=True, metavar='DIR',
                        help='the data set directory to create (never overwritten)')
    parser.add_argument('--fps', type=int, default=10,
                        help='frames per second sampled from the recordings (default: 10)')
    parser.add_argument('--repo-id', default='', metavar='NAME',
                        help='the Hugging Face hub name of the data set, for its card '
                        '(default: local/DIR)')
    parser.add_argument('--task', default=DEFAULT_TASK,
                        help=f'the task of every episode, in words (default: {DEFAULT_TASK!r})')
    parser.add_argument('--namespace', default='',
                        help='the namespace the graph ran in (its topics under it)')
    options = parser.parse_args(args)

    def warn(text: str) -> None:
        print(f'to_lerobot: {text}', file=sys.stderr)

    try:
        summary = export(options.recordings, options.output, options.fps, options.repo_id,
                         options.task, options.namespace, warn)
    except ExportError as error:
        print(f'to_lerobot: {error}', file=sys.stderr)
        return 1
    unmarked = summary.episodes - summary.successes - summary.failures
    print(f'to_lerobot: wrote {options.output}: {summary.episodes} episodes ({summary.successes} '
          f'success, {summary.failures} failure, {unmarked} unmarked), {summary.frames} frames at '
          f'{options.fps} fps, camera video {summary.codec}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
