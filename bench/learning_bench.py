"""Benchmark of the learning environments and the shipped Reach and Pick policies.

Environment steps per second with random actions (episodes reset as they end): one
environment in this process, and the physics steps it takes per second against those of its
world stepped by pybullet alone (what the environment's own work leaves of the physics), with
the share of its time spent in its physics steps, timed where it takes them (its own work is
the rest), and its world stepped with the arm moving (a motor command, then a step); Reach
with more physics steps per action than its task takes (the same rows);
``gymnasium.vector.AsyncVectorEnv`` with one worker process per core (every step a round trip
from this process to each worker), with the Reach environment and with an environment that
does nothing but has Reach's spaces and info (the most AsyncVectorEnv itself can deliver
here); one process per core, each stepping its own environment (as distributed trainers'
environment runners do). Then the shipped Reach and Pick policies over 100 held-out
episodes (evaluate_policy's seeds), with the training wall time their policy.json recorded
(the Pick policy in the live graph is in motion_bench, beside pick_ball). No torch needed.
Run alone: python -m bench.learning_bench
"""

from collections.abc import Callable
import multiprocessing
import os
import time
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
from ur_rg2_learning import PICK_ID, REACH_ID
from ur_rg2_learning.actor import Actor, shipped_policy
from ur_rg2_learning.envs import UrRg2Env
from ur_rg2_learning.evaluate import DEFAULT_SEED, success_rate
from ur_rg2_learning.robot import CONTROL_RATE
from ur_rg2_learning.scripted import pick_action

from bench.processes import load, raw_steps_per_second

STEPS = {REACH_ID: 6000, PICK_ID: 2000}
# Physics share: this many env steps, then the env's world stepped alone as long, in turns.
SHARE_STEPS = {REACH_ID: 1500, PICK_ID: 500}
SHARE_ROUNDS = 3
# Reach stepped with this many physics steps per action (the shipped task takes 1), to show
# where more physics per action takes the first row.
FINER_SUBSTEPS = (4, 10, 24)
MOVING_STEPS = 3000  # physics steps of the world with its arm moving
VECTOR_STEPS = 3000  # per worker
EPISODES = 100


def single_rate(env_id: str, steps: int) -> float:
    """Return steps/s of one environment in this process."""
    return single_rates(env_id, steps)[0]


def single_rates(env_id: str, steps: int) -> tuple[float, float]:
    """Return steps/s of one environment in this process, and steps per CPU second.

    The second is this process's CPU time only: it does not fall when other processes
    share the cores (the wall-clock rate does), so it stands for the idle machine's rate.
    """
    env = gym.make(env_id)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps, *env.action_space.shape)).astype(np.float32)
    try:
        env.reset(seed=0)
        started, cpu = time.perf_counter(), time.process_time()
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        return (steps / (time.perf_counter() - started),
                steps / (time.process_time() - cpu))
    finally:
        env.close()


class PhysicsShare(NamedTuple):
    """An env's physics against stepSimulation's, in one run (steps/s each)."""

    physics: float  # env steps/s times the physics steps each took
    raw: float  # stepSimulation alone on the env's world, between the env's rounds
    inside: float  # the env's own physics steps, timed where the env takes them
    steps: float  # env steps/s
    moving: float  # stepSimulation alone on the env's world, its arm moving

    @property
    def share(self) -> float:
        """Of the env's time, the part in its own physics steps."""
        return self.physics / self.inside


def physics_share(env: gym.Env, steps: int, rounds: int) -> PhysicsShare:
    """Return ``env``'s physics rates against stepSimulation's alone on its world; close it.

    Env steps with random actions (episodes reset as they end), the physics steps each took
    on average, and how long those took, each timed where the env takes it. In turns, so
    that the machine's drift hits both alike: ``steps`` env steps, then the env's world
    stepped by pybullet alone for as long, ``rounds`` times.
    """
    world = env.unwrapped.world
    step_world, in_physics = world.step, [0.0]

    def timed_step() -> None:
        started = time.perf_counter()
        step_world()
        in_physics[0] += time.perf_counter() - started

    world.step = timed_step  # the env's own calls, as it makes them
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps, *env.action_space.shape)).astype(np.float32)
    physics, elapsed, raw = 0, 0.0, []
    try:
        env.reset(seed=0)
        for _ in range(rounds):
            taken, started = world.steps, time.perf_counter()
            for action in actions:
                _, _, terminated, truncated, _ = env.step(action)
                if terminated or truncated:
                    env.reset()
            seconds = time.perf_counter() - started
            physics += world.steps - taken
            elapsed += seconds
            raw.append(raw_steps_per_second(world, seconds))
        env.reset(seed=0)
        moving = moving_rate(env.unwrapped, MOVING_STEPS)
    finally:
        env.close()
    return PhysicsShare(physics / elapsed, sum(raw) / len(raw), physics / in_physics[0],
                        rounds * steps / elapsed, moving)


def finer_reach(substeps: int) -> gym.Env:
    """Return Reach with ``substeps`` physics steps per action, the motor command once."""
    env = gym.make(REACH_ID)
    env.unwrapped.robot.substeps = substeps
    env.unwrapped.world.set_physics_rate(CONTROL_RATE * substeps)
    return env


def moving_rate(env: UrRg2Env, steps: int) -> float:
    """Return physics steps/s of ``env``'s world with its arm moving, nothing else between.

    Each step a new motor command (the joints on a smooth path around the reset's posture),
    then stepSimulation, which alone is timed: the physics of a moving arm, as in the env's
    steps, without the env's work between them.
    """
    import pybullet

    world, start = env.world, np.asarray(env.robot.joints)
    path = start + 0.3 * np.sin(np.arange(len(start)) + 0.05 * np.arange(steps)[:, None])
    still, elapsed = [0.0] * len(start), 0.0
    for target in path.tolist():
        world.drive_arm(target, still)
        started = time.perf_counter()
        pybullet.stepSimulation(physicsClientId=world.client)
        elapsed += time.perf_counter() - started
    return steps / elapsed


class NullEnv(gym.Env):
    """An environment that does no work, with another's spaces and the same kind of info.

    Its steps/s under AsyncVectorEnv are the vector environment's own ceiling: the pipe round
    trips, pickling, shared-memory copies and info merging, with nothing to wait for.
    """

    def __init__(self, observation_space: gym.Space, action_space: gym.Space) -> None:
        self.observation_space, self.action_space = observation_space, action_space
        self._observation = observation_space.sample()

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        """Return the one observation there is."""
        super().reset(seed=seed)
        return self._observation, {'is_success': False}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        """Return the one observation there is, reward 0, never done."""
        return self._observation, 0.0, False, False, {'is_success': False}


def null_env(env_id: str) -> Callable[[], gym.Env]:
    """Return a maker of :class:`NullEnv` with ``env_id``'s spaces, time limit and checks."""
    env = gym.make(env_id)
    spaces = (env.observation_space, env.action_space)
    env.close()
    return lambda: gym.wrappers.TimeLimit(NullEnv(*spaces), env.spec.max_episode_steps)


def vector_rate(make_env: Callable[[], gym.Env], workers: int, steps: int,
                **options: Any) -> float:
    """Return total steps/s of ``workers`` environments, one process each (autoreset).

    ``options`` go to AsyncVectorEnv (``shared_memory``, ``copy``, ...).
    """
    envs = gym.vector.AsyncVectorEnv([make_env] * workers, **options)
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
        rate, per_cpu = single_rates(env_id, steps)
        target = '>= 2000' if env_id == REACH_ID else '>= 1500'
        rows.append((f'{env_id} env steps/s, 1 process, camera off, random actions',
                     f'{rate:.0f} (load {load()}); {per_cpu:.0f} per CPU second', target))
    for env_id, steps in SHARE_STEPS.items():
        loads = [load()]
        share = physics_share(gym.make(env_id), steps, SHARE_ROUNDS)
        loads.append(load())
        rows.append((f'{env_id}: env steps/s x physics steps per env step / stepSimulation '
                     'alone on its world, this run',
                     f"{share.steps:.0f} x {share.physics / share.steps:.2f} = "
                     f"{share.physics:,.0f} / {share.raw:,.0f} = {share.physics / share.raw:.2f} "
                     f"(load {'-'.join(loads)})", '>= 0.8'))
        rows.append((f'{env_id}: of its time, the share in its own physics steps (timed in '
                     'the env); those steps/s / stepSimulation alone, the same run',
                     f'{share.share:.2f}; {share.inside:,.0f} / {share.raw:,.0f} = '
                     f'{share.inside / share.raw:.2f}', '>= 0.8 (its own work <= 20 %)'))
        rows.append((f'{env_id}: its world stepped alone with the arm moving (a motor command '
                     'each step) / stepSimulation alone at rest, the same run',
                     f'{share.moving:,.0f} / {share.raw:,.0f} = {share.moving / share.raw:.2f}',
                     '-'))
    for substeps in FINER_SUBSTEPS:
        share = physics_share(finer_reach(substeps), SHARE_STEPS[REACH_ID], SHARE_ROUNDS)
        rows.append((f"{REACH_ID} with {substeps} physics steps per action (not the task's "
                     '1): env physics / stepSimulation alone; share in its own physics; its '
                     'physics steps/s / stepSimulation alone',
                     f'{share.physics / share.raw:.2f}; {share.share:.2f}; '
                     f'{share.inside / share.raw:.2f} (load {load()})', '-'))
    started = time.process_time()
    success = success_rate(pick_action, EPISODES, DEFAULT_SEED, PICK_ID)
    rows.append((f'{PICK_ID} scripted demonstrator: success over {EPISODES} held-out episodes',
                 f'{success:.2f} ({time.process_time() - started:.0f} CPU s)', '>= 0.99'))
    rate = vector_rate(lambda: gym.make(REACH_ID), cores, VECTOR_STEPS)
    rows.append((f'{REACH_ID} env steps/s, AsyncVectorEnv, {cores} workers (1 per core)',
                 f'{rate:.0f} ({rate / cores:.0f} per core)', '>= 2000 per core'))
    rate = vector_rate(null_env(REACH_ID), cores, VECTOR_STEPS)
    rows.append((f'AsyncVectorEnv alone: env with no work, {REACH_ID} spaces, {cores} workers',
                 f'{rate:.0f} ({rate / cores:.0f} per core)', '-'))
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
    actor = Actor.load(shipped_policy('pick'))
    success = success_rate(actor, EPISODES, DEFAULT_SEED)
    minutes = actor.meta['train_seconds'] / 60
    method = actor.meta.get('method', actor.meta['algo'])
    rows.append((f'{PICK_ID} shipped policy ({method}): success over {EPISODES} held-out '
                 'episodes', f'{success:.2f}', '>= 0.95'))
    rows.append((f'{PICK_ID}: training wall time ({actor.meta["timesteps"]} steps, recorded '
                 'by train_policy)', f'{minutes:.1f} min', '<= 60 min'))
    return rows


if __name__ == '__main__':
    from bench.__main__ import print_table

    print_table(run())
