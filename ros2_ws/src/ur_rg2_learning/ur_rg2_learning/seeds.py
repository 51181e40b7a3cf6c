"""``train_policy --seeds``: each seed a Ray task, then one table and one picture.

Each task (:func:`ur_rg2_learning.ray_tasks.ray_map`: a local Ray, or an existing cluster)
returns its actors and curve as plain data, so the workers need no shared disk: this process
writes ``seed_N/`` for each seed, ``seeds.md`` (the table) and ``seeds.png`` (the curves).
Only train_policy imports this module; nothing on the run path needs Ray.

``python -m ur_rg2_learning.seeds DIR ...`` prints the same table for seeds trained one per
process (``train_policy --seed N --out DIR``), from what each wrote.
"""

from __future__ import annotations

from pathlib import Path
import sys
from typing import Any

from ur_rg2_learning.actor import Actor, write_atomically
from ur_rg2_learning.ray_tasks import markdown_table, ray_map
from ur_rg2_learning.train_config import TrainConfig
from ur_rg2_learning.training_run import plot_curves, summary, train_seed, write_result


def run_seeds(config: TrainConfig, seeds: list[int], out: Path, num_cpus: int | None,
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


def written_result(directory: Path) -> dict[str, Any]:
    """Return a written seed's row of the table: its policy.json, its best/ and held-out scores."""
    meta = Actor.load(directory).meta
    best = Actor.load(directory / 'best').meta['best_of_curve']
    held_out = meta['held_out']
    return {'seed': meta['seed'], 'final': held_out['final_success'],
            'before_rl': held_out['before_rl_success'], 'final_episodes': held_out['episodes'],
            'best_success': best['success'], 'best_steps': best['steps'],
            'steps': meta['timesteps'], 'seconds': meta['train_seconds']}


def main(argv: list[str] | None = None) -> int:
    """Print the seeds' table of the train_policy --out directories given; exit code 0."""
    directories = sys.argv[1:] if argv is None else argv
    if not directories:
        print('usage: python -m ur_rg2_learning.seeds DIR ... (train_policy --out directories)',
              file=sys.stderr)
        return 2
    print(table([written_result(Path(directory)) for directory in directories]), end='')
    return 0


if __name__ == '__main__':
    sys.exit(main())
