"""Run every benchmark and print one table: ``python -m bench [name ...]``.

Names: sim, frames, controllers, teleop, vision, detector, viewer, record, dataset, motion,
learning, setup, launch, discovery, graph, soak (default: all; soak alone takes 10 minutes,
SOAK_SECONDS sets its length; graph takes GRAPH_SECONDS, 60 by default, and a warm-up).
Each module's ``run()`` returns rows of (metric, measured, target). The numbers mean most on
an otherwise idle machine.
"""

import argparse
import importlib
import sys
import time

BENCHMARKS = ('sim', 'frames', 'controllers', 'teleop', 'vision', 'detector', 'viewer',
              'record', 'dataset', 'motion', 'learning', 'setup', 'launch', 'discovery', 'graph',
              'soak')


def print_table(rows: list[tuple[str, str, str]]) -> None:
    """Print rows as a Markdown table (ready to paste into docs/benchmark.md)."""
    header = ('metric', 'measured', 'target')
    widths = [max(len(str(row[i])) for row in [header, *rows]) for i in range(3)]
    for row in [header, tuple('-' * w for w in widths), *rows]:
        print('| ' + ' | '.join(str(c).ljust(w) for c, w in zip(row, widths)) + ' |')


def main() -> int:
    """Run the chosen benchmarks and print their rows."""
    parser = argparse.ArgumentParser(prog='python -m bench', description=__doc__.splitlines()[0])
    parser.add_argument('names', nargs='*', metavar='name',
                        help=f"benchmarks to run: {', '.join(BENCHMARKS)} (default: all)")
    names = parser.parse_args().names or BENCHMARKS
    unknown = sorted(set(names) - set(BENCHMARKS))
    if unknown:
        parser.error(f"unknown benchmark {', '.join(unknown)}; choose from "
                     f"{', '.join(BENCHMARKS)}")
    rows = []
    for name in names:
        started = time.monotonic()
        print(f'running {name} benchmark ...', file=sys.stderr, flush=True)
        module = importlib.import_module(f'bench.{name}_bench')
        rows += module.run()
        print(f'  {name} done in {time.monotonic() - started:.0f} s', file=sys.stderr)
    print_table(rows)
    return 0


if __name__ == '__main__':
    sys.exit(main())
