"""``train_policy --seeds``: each seed a Ray task, then one table and one picture.

Each task (:func:`ur_rg2_learning.ray_tasks.ray_map`: a local Ray, or an existing cluster)
returns its actors and curve as plain data, so the workers need no shared disk: this process
writes ``seed_N/`` for each seed, ``seeds.md`` (the table) and ``seeds.png`` (the curves).
Only train_policy imports this module; nothing on the run path needs Ray.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ur_rg2_learning.actor import write_atomically
from ur_rg2_learning.ray_tasks import markdown_table, ray_map
from ur_rg2_learning.train import plot_curves, summary, train_seed, write_result


def run_seeds(config: dict[str, Any], seeds: list[int], out: Path, num_cpus: int | None,
              address: str | None) -> int:
    """Train ``seeds`` as Ray tasks; write each, the table and the picture; return 0."""
    results = ray_map(train_seed, [(config, seed) for seed in seeds], num_cpus, address)
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
    return markdown_table(rows)
