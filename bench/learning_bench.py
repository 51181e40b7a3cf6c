"""Benchmark of the learning environments and the shipped Reach policy.

Environment steps per second with random actions (episodes reset as they end): one
environment in this process; ``gymnasium.vector.AsyncVectorEnv`` with one worker process per
core (every step a round trip from this process to each worker); one process per core, each
stepping its own environment (as distributed trainers' environment runners do). Then the
shipped Reach policy over 100 held-out episodes (evaluate_policy's seeds), with the training
wall time its policy.json recorded. No torch needed.
Run alone: python -m bench.learning_bench
"""

import multiprocessing
import os
import time

import gymnasium as gym
import numpy as np
from ur_rg2_learning import PICK_ID, REACH_ID
from ur_rg2_learning.actor import Actor
from ur_rg2_learning.evaluate import DEFAULT_SEED, success_rate
from ur_rg2_learning.policy_node import shipped_policy

STEPS = {REACH_ID: 6000, PICK_ID: 2000}
VECTOR_STEPS = 3000  # per worker
EPISODES = 100


def single_rate(env_id: str, steps: int) -> float:
    """Return steps/s of one environment in this process."""
    env = gym.make(env_id)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps, *env.action_space.shape)).astype(np.float32)
    try:
        env.reset(seed=0)
        started = time.perf_counter()
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        return steps / (time.perf_counter() - started)
    finally:
        env.close()


def vector_rate(env_id: str, workers: int, steps: int) -> float:
    """Return total steps/s of ``workers`` environments, one process each (autoreset)."""
    envs = gym.vector.AsyncVectorEnv([lambda: gym.make(env_id)] * workers)
    rng = np.random.default_rng(0)
    try:
        envs.reset(seed=list(range(workers)))
        envs.step(envs.action_space.sample())  # the workers are up and warm
        actions = rng.uniform(-1, 1, (steps, *envs.action_space.shape)).astype(np.float32)
        started = time.perf_counter()
        for action in actions:
            envs.step(action)
        return steps * workers / (time.perf_counter() - started)
    finally:
        envs.close()


def parallel_rate(env_id: str, workers: int, steps: int) -> float:
    """Return total steps/s of ``workers`` processes, each stepping its own environment.

    The way distributed trainers' environment runners work (RLlib's, for one): each steps
    locally and ships batches, so no per-step round trip to a central process.
    """
    with multiprocessing.get_context('spawn').Pool(workers) as pool:
        return sum(pool.starmap(single_rate, [(env_id, steps)] * workers))


def run() -> list[tuple[str, str, str]]:
    """Return the benchmark's rows: (metric, measured, target)."""
    cores = len(os.sched_getaffinity(0))
    rows = []
    for env_id, steps in STEPS.items():
        rate = single_rate(env_id, steps)
        target = '>= 2000' if env_id == REACH_ID else '-'
        rows.append((f'{env_id} env steps/s, 1 process, camera off', f'{rate:.0f}', target))
    rate = vector_rate(REACH_ID, cores, VECTOR_STEPS)
    rows.append((f'{REACH_ID} env steps/s, AsyncVectorEnv, {cores} workers (1 per core)',
                 f'{rate:.0f} ({rate / cores:.0f} per core)', '>= 2000 per core'))
    rate = parallel_rate(REACH_ID, cores, STEPS[REACH_ID])
    rows.append((f'{REACH_ID} env steps/s, {cores} processes stepping their own env',
                 f'{rate:.0f} ({rate / cores:.0f} per core)', '>= 2000 per core'))
    actor = Actor.load(shipped_policy())
    success = success_rate(actor, EPISODES, DEFAULT_SEED)
    minutes = actor.meta['train_seconds'] / 60
    rows.append((f'{REACH_ID} DDPG + HER (shipped policy): success over {EPISODES} held-out '
                 'episodes', f'{success:.2f}', '>= 0.95'))
    rows.append((f'{REACH_ID} DDPG + HER: training wall time ({actor.meta["timesteps"]} steps, '
                 'recorded by train_policy)', f'{minutes:.1f} min', '<= 20 min'))
    return rows


if __name__ == '__main__':
    from bench.__main__ import print_table

    print_table(run())
