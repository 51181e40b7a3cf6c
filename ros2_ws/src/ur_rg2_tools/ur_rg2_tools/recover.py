"""``recover``: a recording cut short (recorder killed, disk full) to a complete MCAP file.

``ros2 run ur_rg2_tools recover FILE [-o OUT]`` keeps every message of the chunks written
before the cut, as the mcap CLI's ``mcap recover`` does; no ROS needed.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys

from ur_rg2_tools.bag import RecordingError, recover


def main(args: list[str] | None = None) -> int:
    """Write FILE's readable messages to OUT; exit 1 when FILE is missing or no MCAP."""
    parser = argparse.ArgumentParser(prog='recover', description=__doc__.splitlines()[0])
    parser.add_argument('file', metavar='FILE', help='the recording cut short')
    parser.add_argument('-o', '--output', metavar='OUT',
                        help='where to write the complete file (default: FILE-recovered.mcap)')
    options = parser.parse_args(args)
    source = Path(options.file)
    target = Path(options.output or source.with_name(f'{source.stem}-recovered.mcap'))
    try:
        result = recover(source, target)
    except RecordingError as error:
        print(f'recover: {error}', file=sys.stderr)
        return 1
    ending = (f'reading stopped at an incomplete record ({result.error})' if result.error
              else 'the file was complete')
    print(f'recover: {result.messages} messages written to {target}; {ending}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
