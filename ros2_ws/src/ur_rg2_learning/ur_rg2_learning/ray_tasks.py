"""Calls run as Ray tasks (a learning command's ``--seeds``), and a table of their results.

Ray runs locally (``ray.init(num_cpus=...)``) unless an address names an existing cluster
(``auto``, or ``HOST:PORT`` of a head started with ``ray start --head``). Only the learning
commands' ``--seeds`` import this module; nothing on the run path needs Ray.
"""

from __future__ import annotations

from collections.abc import Callable
import os
from typing import Any


def ray_map(function: Callable[..., Any], calls: list[tuple], num_cpus: int | None,
            address: str | None) -> list[Any]:
    """Return ``function(*call)`` for each call, each a Ray task, in the calls' order.

    Each task takes one CPU where the cluster has one per call, else an equal share of them.
    ``function`` must be importable by the workers (a module's top-level function) and return
    plain data: the workers need no disk shared with this process.
    """
    # Set before Ray is imported, which reads them. Every task's output lines, not one of
    # several alike (Ray's default).
    os.environ.setdefault('RAY_DEDUP_LOGS', '0')
    os.environ.setdefault('RAY_USAGE_STATS_ENABLED', '0')  # nothing sent anywhere
    # A local Ray's workers run at the command's priority (Ray's default lowers them by 15,
    # below everything else on the machine: a loaded 2-core machine then starves the tasks).
    # Run the command under `nice` to yield.
    os.environ.setdefault('RAY_worker_niceness', '0')
    import ray

    if address:
        ray.init(address=address, include_dashboard=False, log_to_driver=True)
    else:
        ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=True)
    try:
        cpus = ray.cluster_resources().get('CPU', 1.0)
        task = ray.remote(num_cpus=min(1.0, cpus / len(calls)), max_retries=0)(function)
        return ray.get([task.remote(*call) for call in calls])
    finally:
        ray.shutdown()


def markdown_table(rows: list[tuple[str, ...]]) -> str:
    """Return rows (the first the header) as a Markdown table, columns aligned."""
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = ['| ' + ' | '.join(c.ljust(w) for c, w in zip(row, widths)) + ' |' for row in rows]
    lines.insert(1, '| ' + ' | '.join('-' * w for w in widths) + ' |')
    return '\n'.join(lines) + '\n'
