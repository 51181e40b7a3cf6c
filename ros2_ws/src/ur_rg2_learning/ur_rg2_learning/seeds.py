"""``train_policy --seeds``: each seed a Ray task, then one table and one picture.

Ray runs locally (``ray.init(num_cpus=...)``) unless an address names an existing cluster
(``auto``, or ``HOST:PORT`` of a head started with ``ray start --head``). Each task returns
its actors and curve as plain data, so the workers need no shared disk: this process writes
``seed_N/`` for each seed, ``seeds.md`` (the table) and ``seeds.png`` (the curves). Only
train_policy imports this module; nothing on the run path needs Ray.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from ur_rg2_learning.actor import write_atomically
from ur_rg2_learning.train import plot_curves, summary, train_seed, write_result


def run_seeds(config: dict[str, Any], seeds: list[int], out: Path, num_cpus: int | None,
              address: str | None) -> int:
    """Train ``seeds`` as Ray tasks; write each, the table and the picture; return 0."""
    # Set before Ray is imported, which reads them. Every seed's curve lines, not one of
    # several alike (Ray's default).
    os.environ.setdefault('RAY_DEDUP_LOGS', '0')
    os.environ.setdefault('RAY_USAGE_STATS_ENABLED', '0')  # nothing sent anywhere
    # A local Ray's workers run at the command's priority (Ray's default lowers them by 15,
    # below everything else on the machine: a loaded 2-core machine then starves the seeds).
    # Run the command under `nice` to yield.
    os.environ.setdefault('RAY_worker_niceness', '0')
    import ray

    if address:
        ray.init(address=address, include_dashboard=False, log_to_driver=True)
    else:
        ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=True)
    try:
        # One CPU per seed where the cluster has them, else an equal share of what there is.
        cpus = ray.cluster_resources().get('CPU', 1.0)
        per_seed = min(1.0, cpus / len(seeds))
        task = ray.remote(num_cpus=per_seed, max_retries=0)(train_seed)
        results = ray.get([task.remote(config, seed) for seed in seeds])
    finally:
        ray.shutdown()
    out.mkdir(parents=True, exist_ok=True)
    for result in results:
        write_result(result, out / f'seed_{result["seed"]}')
        print(summary(result, out / f'seed_{result["seed"]}'))
    text = table(results)
    write_atomically(out / 'seeds.md', lambda f: f.write(text.encode()))
    plot_curves({result['seed']: result['curve'] for result in results},
                f"{results[0]['env']}, {results[0]['method']}", out / 'seeds.png')
    print(text, end='')
    return 0


def table(results: list[dict[str, Any]]) -> str:
    """Return the seeds' Markdown table: final, best and before-RL success, steps, wall time."""
    episodes = results[0]['final_episodes']
    rows = [('seed', f'final success ({episodes} held-out)', 'best curve point',
             f'before RL ({episodes} held-out)', 'env steps', 'wall time')]
    for r in sorted(results, key=lambda result: result['seed']):
        rows.append((str(r['seed']), f"{r['final']:.2f}",
                     f"{r['best_success']:.2f} at {r['best_steps']}", f"{r['before_rl']:.2f}",
                     str(r['steps']), f"{r['seconds'] / 60:.1f} min"))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = ['| ' + ' | '.join(c.ljust(w) for c, w in zip(row, widths)) + ' |' for row in rows]
    lines.insert(1, '| ' + ' | '.join('-' * w for w in widths) + ' |')
    return '\n'.join(lines) + '\n'
