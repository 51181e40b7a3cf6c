"""Seeded rollouts of Reach and Pick pinned to recorded values: the tasks do not drift.

Observations, rewards, terminations, success flags and the arm's and fingers' joint positions
after every step of a few seeded rollouts (random actions, the scripted pick, grasped and
over-ball starts, a push out of reach) must equal the values recorded in
``tests/data/learning_rollouts.npz`` to within 1e-9: a change meant to make the environments
faster must leave what they compute alone. Record anew (only for a deliberate change of a
task) with ``python tests/test_learning_rollouts.py --record``.
"""

from pathlib import Path
import sys

import gymnasium as gym
import numpy as np
import pytest
from ur_rg2_learning import PICK_ID, REACH_ID
from ur_rg2_learning.scripted import pick_action

RECORDED = Path(__file__).parent / 'data' / 'learning_rollouts.npz'
TOLERANCE = 1e-9


def _row(env: gym.Env, observation: dict, reward: float, terminated: bool, truncated: bool,
         info: dict) -> np.ndarray:
    joints = env.unwrapped.world.joint_states().positions
    return np.concatenate([observation['observation'], observation['achieved_goal'],
                           observation['desired_goal'],
                           [reward, terminated, truncated, info['is_success']], joints])


def _run(env: gym.Env, steps: int, policy, **reset: dict) -> list[np.ndarray]:
    observation, info = env.reset(**reset)
    rows = [_row(env, observation, 0.0, False, False, info)]
    for _ in range(steps):
        observation, reward, terminated, truncated, info = env.step(policy(observation))
        rows.append(_row(env, observation, reward, terminated, truncated, info))
        if terminated or truncated:
            observation, info = env.reset()
            rows.append(_row(env, observation, 0.0, False, False, info))
    return rows


def reach_rollout() -> np.ndarray:
    """Return Reach's rows: random actions over an episode's end, pushes out of reach and in."""
    env = gym.make(REACH_ID)
    try:
        env.action_space.seed(3)
        rows = _run(env, 60, lambda _: env.action_space.sample(), seed=7)
        push = np.array([1.0, -0.3, 1.0], dtype=np.float32)  # on to the edge of the reach
        rows += _run(env, 25, lambda _: push, seed=8)
        pull = np.array([-1.0, 0.3, -1.0], dtype=np.float32)  # into the pedestal
        rows += _run(env, 20, lambda _: pull, seed=9)
        return np.array(rows)
    finally:
        env.close()


def pick_rollout() -> np.ndarray:
    """Return Pick's rows: scripted picks, random actions, grasped and over-ball starts."""
    env = gym.make(PICK_ID, grasped_share=0.3, over_ball_share=0.3)
    try:
        env.action_space.seed(5)
        rows = _run(env, 40, pick_action, seed=11)  # down to the ball, the grasp, the lift
        rows += _run(env, 30, lambda _: env.action_space.sample(), seed=12,
                     options={'grasped': True})
        rows += _run(env, 20, pick_action, seed=13, options={'over_ball': True})
        for seed in (14, 15, 16):  # drawn starts
            rows += _run(env, 12, lambda _: env.action_space.sample(), seed=seed)
        return np.array(rows)
    finally:
        env.close()


ROLLOUTS = {REACH_ID: reach_rollout, PICK_ID: pick_rollout}


@pytest.mark.parametrize('env_id', [REACH_ID, PICK_ID])
def test_a_seeded_rollout_gives_the_recorded_values(env_id):
    recorded = np.load(RECORDED)[env_id]
    rows = ROLLOUTS[env_id]()
    assert rows.shape == recorded.shape
    np.testing.assert_allclose(rows, recorded, rtol=0.0, atol=TOLERANCE)


if __name__ == '__main__' and sys.argv[1:] == ['--record']:
    RECORDED.parent.mkdir(exist_ok=True)
    np.savez_compressed(RECORDED, **{env_id: make() for env_id, make in ROLLOUTS.items()})
    print(f'recorded {RECORDED}')
