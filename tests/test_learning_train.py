"""train_policy and evaluate_policy end to end: a short DDPG + HER run must beat random actions.

The learning set-up (torch, Stable-Baselines3, matplotlib) comes with requirements-dev.txt,
so this runs the real training code. It stays short (Reach: about 1,500 environment steps;
Pick: 30 scripted demonstrations cloned, 100 steps): enough for the policy to do better than
random actions do, not to master the task (the shipped policies and the benchmark measure
that).
"""

from pathlib import Path
import re
import subprocess
import sys

import gymnasium as gym
import numpy as np
from ur_rg2_learning import PICK_ID, REACH_ID
from ur_rg2_learning.actor import Actor
from ur_rg2_learning.evaluate import success_rate

BIN = Path(sys.executable).parent
STEPS = 1500
EPISODES = 10
SEED = 1_000_000  # held out: training seeds its environment with 0


def final_distances(policy, episodes: int) -> np.ndarray:
    """Return the TCP's distance to the ball's top at the end of each held-out episode."""
    env = gym.make(REACH_ID)
    distances = []
    try:
        for episode in range(episodes):
            observation, _ = env.reset(seed=SEED + episode)
            done = False
            while not done:
                observation, reward, terminated, truncated, _ = env.step(policy(observation))
                done = terminated or truncated
            distances.append(-reward)
    finally:
        env.close()
    return np.array(distances)


def test_train_save_load_evaluate(tmp_path):
    out = tmp_path / 'reach'
    trained = subprocess.run(
        [str(BIN / 'train_policy'), '--env', REACH_ID, '--algo', 'ddpg', '--timesteps',
         str(STEPS), '--seed', '0', '--out', str(out), '--eval-every', str(STEPS),
         '--eval-episodes', '5'], capture_output=True, text=True, timeout=300)
    assert trained.returncode == 0, trained.stderr
    assert f'{STEPS}/{STEPS} steps' in trained.stdout  # progress
    assert {'actor.npz', 'policy.json', 'model.zip', 'learning_curve.png'} <= {
        p.name for p in out.iterdir()}
    assert (out / 'learning_curve.png').read_bytes().startswith(b'\x89PNG')
    assert Actor.load(out / 'best').meta['best_of_curve']['steps'] == STEPS  # one curve point

    actor = Actor.load(out)
    assert actor.env_id == REACH_ID and actor.meta['timesteps'] == STEPS
    # The NumPy actor is the trained network: same actions as Stable-Baselines3's model.
    from stable_baselines3 import DDPG
    env = gym.make(REACH_ID)
    try:
        model = DDPG.load(out / 'model.zip', env=env, device='cpu')  # HER needs the env
        observation, _ = env.reset(seed=SEED)
        for _ in range(5):
            expected, _ = model.predict(observation, deterministic=True)
            assert np.allclose(actor(observation), expected, atol=1e-5)
            observation = env.step(expected)[0]
    finally:
        env.close()

    rng = np.random.default_rng(0)
    learned = final_distances(actor, EPISODES)
    random = final_distances(lambda _: rng.uniform(-1, 1, 3), EPISODES)
    assert learned.mean() < 0.5 * random.mean(), (learned, random)

    evaluated = subprocess.run(
        [str(BIN / 'evaluate_policy'), '--policy', str(out), '--episodes', '5'],
        capture_output=True, text=True, timeout=120)
    assert evaluated.returncode == 0, evaluated.stderr
    assert re.fullmatch(r'success rate [01]\.\d\d over 5 episodes\n', evaluated.stdout)


def test_a_short_pick_run_with_cloned_demonstrations_beats_random(tmp_path):
    """DDPG + HER + scripted demonstrations with behaviour cloning: lifts where random can't."""
    out = tmp_path / 'pick'
    trained = subprocess.run(
        [str(BIN / 'train_policy'), '--env', PICK_ID, '--algo', 'ddpg', '--timesteps', '100',
         '--seed', '0', '--out', str(out), '--demos', '30', '--pretrain', '3000', '--bc', '2.5',
         '--no-q-filter', '--eval-every', '100', '--eval-episodes', '1'],
        capture_output=True, text=True, timeout=400)
    assert trained.returncode == 0, trained.stderr
    actor = Actor.load(out)
    assert actor.env_id == PICK_ID and actor.meta['demos'] == 30 and actor.meta['bc'] == 2.5
    rng = np.random.default_rng(0)
    learned = round(success_rate(actor, EPISODES, SEED) * EPISODES)
    random = round(success_rate(lambda _: rng.uniform(-1, 1, 4), EPISODES, SEED, PICK_ID)
                   * EPISODES)
    assert learned >= 3 and random == 0, (learned, random)


def test_evaluate_policy_refuses_a_directory_without_a_policy(tmp_path):
    done = subprocess.run([str(BIN / 'evaluate_policy'), '--policy', str(tmp_path)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert done.stderr.startswith('evaluate_policy: no usable policy in')
    assert len(done.stderr.splitlines()) == 1
