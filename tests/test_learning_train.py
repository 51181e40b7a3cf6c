"""train_policy and evaluate_policy end to end, and the training pieces on short runs.

The learning set-up (torch, Stable-Baselines3, matplotlib, Ray) comes with
requirements-dev.txt, so this runs the real training code. The runs stay short: enough to see
each piece do its part (Reach learns to beat random actions in 1,500 steps; Pick's pieces
change what they should), not to master a task (the shipped policies and docs/learning.md's
3-seed table measure that).
"""

import json
import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import time

import gymnasium as gym
import numpy as np
import pytest
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
         '--eval-episodes', '5', '--final-episodes', '5'],
        capture_output=True, text=True, timeout=300)
    assert trained.returncode == 0, trained.stderr
    assert f'{STEPS}/{STEPS} steps' in trained.stdout  # progress
    assert {'actor.npz', 'policy.json', 'learning_curve.png', 'before_rl', 'best'} <= {
        p.name for p in out.iterdir()}
    assert (out / 'learning_curve.png').read_bytes().startswith(b'\x89PNG')
    assert Actor.load(out / 'best').meta['best_of_curve']['steps'] in (0, STEPS)

    actor = Actor.load(out)
    assert actor.env_id == REACH_ID and actor.meta['timesteps'] == STEPS
    assert actor.meta['method'] == 'DDPG + HER'
    assert [point['steps'] for point in actor.meta['curve']] == [0, STEPS]
    rng = np.random.default_rng(0)
    learned = final_distances(actor, EPISODES)
    random = final_distances(lambda _: rng.uniform(-1, 1, 3), EPISODES)
    assert learned.mean() < 0.5 * random.mean(), (learned, random)
    before = final_distances(Actor.load(out / 'before_rl'), EPISODES)
    assert learned.mean() < 0.5 * before.mean(), (learned, before)

    evaluated = subprocess.run(
        [str(BIN / 'evaluate_policy'), '--policy', str(out), '--episodes', '5'],
        capture_output=True, text=True, timeout=120)
    assert evaluated.returncode == 0, evaluated.stderr
    assert re.fullmatch(r'success rate [01]\.\d\d over 5 episodes\n', evaluated.stdout)


def test_the_exported_actor_is_the_network_with_its_input_standardisation():
    from stable_baselines3 import TD3
    from ur_rg2_learning.td3_cloning import StandardisingExtractor
    from ur_rg2_learning.train_config import TrainConfig
    from ur_rg2_learning.training_run import export

    env = gym.make(PICK_ID)
    try:
        rng = np.random.default_rng(0)
        mean, std = rng.normal(0, 0.3, 22).tolist(), rng.uniform(0.01, 1.0, 22).tolist()
        model = TD3('MultiInputPolicy', env, seed=0, policy_kwargs={
            'net_arch': [32, 32], 'features_extractor_class': StandardisingExtractor,
            'features_extractor_kwargs': {'mean': mean, 'std': std}})
        facts = {'seed': 0, 'observation_keys': list(env.observation_space.spaces),
                 'action_low': [-1.0] * 4, 'action_high': [1.0] * 4}
        config = TrainConfig(PICK_ID, net_arch=(32, 32), bc=2.5, clip_return=True)
        actor = export(model, config, facts, 0, 0.0, [])
        # policy.json is written from the config and reads back into it (the run-only
        # fields, not in it, at their defaults).
        assert TrainConfig.from_policy(json.loads(json.dumps(actor.meta))) == config
        observation, _ = env.reset(seed=SEED)
        for _ in range(5):
            expected, _ = model.predict(observation, deterministic=True)
            assert np.allclose(actor(observation), expected, atol=1e-5)
            observation = env.step(expected)[0]
    finally:
        env.close()


def test_the_shipped_policies_read_into_a_train_config():
    from ur_rg2_learning.actor import SHIPPED, shipped_policy
    from ur_rg2_learning.train_config import TrainConfig

    for name in SHIPPED:
        meta = Actor.load(shipped_policy(name)).meta  # older ones lack later fields
        config = TrainConfig.from_policy(meta)
        assert config.env_id == meta['env_id'] and config.algo == meta['algo']
        assert list(config.net_arch) == meta['hyperparameters']['net_arch']
        written = config.policy_fields()
        assert {key: meta[key] for key in written if key in meta} == {
            key: value for key, value in written.items() if key in meta}


def td3_on_pick(env, demonstrations: dict, net: list[int], **cloning):
    """Return a TD3 + HER model on Pick, ``TD3Cloning(**cloning)``, demonstrations in."""
    from stable_baselines3 import HerReplayBuffer
    from ur_rg2_learning.demonstrations import add_demonstrations, input_scaling
    from ur_rg2_learning.td3_cloning import StandardisingExtractor, TD3Cloning

    mean, std = input_scaling(PICK_ID, demonstrations)
    model = TD3Cloning(
        'MultiInputPolicy', env, **cloning, seed=0, batch_size=64, learning_starts=10,
        replay_buffer_class=HerReplayBuffer, policy_kwargs={
            'net_arch': net, 'features_extractor_class': StandardisingExtractor,
            'features_extractor_kwargs': {'mean': mean, 'std': std}})
    add_demonstrations(model.replay_buffer, demonstrations)
    return model


@pytest.fixture(scope='module')
def pick_model():
    """Yield a TD3 + HER model on Pick with 3 scripted demonstrations in its buffer."""
    from ur_rg2_learning.demonstrations import scripted_demonstrations

    demonstrations = scripted_demonstrations(PICK_ID, 3)
    env = gym.make(PICK_ID)
    yield td3_on_pick(env, demonstrations, [64, 64], actor_lr_share=0.1), demonstrations
    env.close()


def test_demonstrations_are_whole_lifts_in_the_buffer(pick_model):
    model, demonstrations = pick_model
    steps = len(demonstrations['action'])
    assert model.replay_buffer.size() == steps
    assert demonstrations['done'].sum() == 3  # three episodes, each ended
    assert (demonstrations['reward'] == 0).sum() >= 3 * 10  # held at the goal for a while


def test_the_critic_warms_up_on_the_demonstrations_and_the_actor_stays(pick_model):
    import torch

    model, demonstrations = pick_model
    actor = [p.detach().clone() for p in model.actor.parameters()]
    keys = list(model.observation_space.spaces)
    observations = {key: torch.as_tensor(demonstrations[key]) for key in keys}
    actions = torch.as_tensor(demonstrations['action'])
    with torch.no_grad():
        before = model.critic.q1_forward(observations, actions).mean().item()
    model.warm_up_critic(200)
    with torch.no_grad():
        after = model.critic.q1_forward(observations, actions).mean().item()
    assert all(torch.equal(a, b) for a, b in zip(actor, model.actor.parameters()))
    # Rewards of -1 until the ball is at its goal: the demonstrated steps' value goes down.
    assert after < before - 0.5, (before, after)


def test_clipped_targets_keep_the_critic_within_the_returns(pick_model):
    import torch

    model, demonstrations = pick_model
    keys = list(model.observation_space.spaces)
    observations = {key: torch.as_tensor(demonstrations[key]) for key in keys}
    actions = torch.as_tensor(demonstrations['action'])
    # Bounds far tighter than the rewards' (-20 to 0 with gamma 0.95): the critic is pulled
    # into them, where unclipped warm-up takes it below (the test above).
    model.q_bounds = (-0.5, 0.0)
    try:
        model.warm_up_critic(300)
    finally:
        model.q_bounds = None
    with torch.no_grad():
        values = torch.cat(model.critic(observations, actions), dim=1)
    assert -0.7 < values.mean().item() < 0.1, values.mean().item()


def test_the_actor_update_adds_cloning_and_an_action_penalty():
    from stable_baselines3.common.logger import Logger
    import torch
    from ur_rg2_learning.demonstrations import Cloning, scripted_demonstrations

    demonstrations = scripted_demonstrations(PICK_ID, 2)
    env = gym.make(PICK_ID)
    keys = list(env.observation_space.spaces)
    observations = {key: torch.as_tensor(demonstrations[key]) for key in keys}
    try:
        moves = {}
        for penalty in (0.0, 100.0):
            model = td3_on_pick(env, demonstrations, [32, 32], actor_lr_share=1.0,
                                q_bounds=(-20.0, 0.0), action_l2=penalty)
            model.set_logger(Logger(None, []))  # train() logs; a Logger with no outputs
            model.cloning = Cloning(model, demonstrations, 1.0)
            model.train(200, 64)
            assert model._n_updates == 200 and 0.0 <= model.cloning.share <= 1.0
            logged = model.logger.name_to_value
            assert {'train/critic_loss', 'train/actor_loss', 'train/cloning_loss'} <= set(logged)
            assert logged['train/cloning_loss'] >= 0.0
            with torch.no_grad():
                moves[penalty] = (model.actor(observations)[:, :3] ** 2).mean().item()
        assert moves[100.0] < 0.5 * moves[0.0], moves
    finally:
        env.close()


def test_cloning_moves_the_actor_toward_the_demonstrated_actions(pick_model):
    import torch
    from ur_rg2_learning.demonstrations import Cloning

    model, demonstrations = pick_model
    cloning = Cloning(model, demonstrations, weight=1.0, q_filter=False)
    keys = list(model.observation_space.spaces)
    observations = {key: torch.as_tensor(demonstrations[key]) for key in keys}
    actions = torch.as_tensor(demonstrations['action'])

    def error() -> float:
        with torch.no_grad():
            return ((model.actor(observations) - actions) ** 2).sum(dim=1).mean().item()

    start = error()
    optimizer = model.actor.optimizer
    for _ in range(100):
        optimizer.zero_grad()
        cloning.loss(64).backward()
        optimizer.step()
    assert error() < 0.7 * start


def test_a_fading_cloning_term_falls_to_nothing(pick_model):
    from ur_rg2_learning.demonstrations import Cloning

    model, demonstrations = pick_model
    cloning = Cloning(model, demonstrations, weight=1.0, q_filter=False, fade=100)
    try:
        model.num_timesteps = 50
        assert cloning.loss(64).item() > 0.0
        model.num_timesteps = 100
        assert cloning.loss(64).item() == 0.0
    finally:
        model.num_timesteps = 0


def test_a_short_pick_run_records_what_trained_it(tmp_path):
    out = tmp_path / 'pick'
    trained = subprocess.run(
        [str(BIN / 'train_policy'), '--env', PICK_ID, '--timesteps', '100', '--seed', '0',
         '--out', str(out), '--demos', '2', '--bc', '2.5', '--critic-warmup', '20',
         '--grasped-share', '0.5', '--net', '32', '32', '--eval-every', '100',
         '--eval-episodes', '1', '--final-episodes', '2', '--obs-noise', 'vision'],
        capture_output=True, text=True, timeout=400)
    assert trained.returncode == 0, trained.stderr
    actor = Actor.load(out)
    meta = actor.meta
    assert actor.env_id == PICK_ID and meta['algo'] == 'td3' and meta['demos'] == 2
    assert meta['method'] == ('TD3 + HER + 2 scripted demos in the buffer + Q-filtered BC 2.5, '
                              'critic warm-up 20, 0.5 of episodes start grasped, ball '
                              'observed with 1.3 mm noise')
    assert meta['cloned_before_rl'] == 0 and meta['timesteps'] == 100
    assert meta['obs_noise_mm'] == 1.3 and meta['held_out']['obs_noise_mm'] == 1.3
    assert set(meta['held_out']) == {'episodes', 'seed', 'obs_noise_mm', 'final_success',
                                     'before_rl_success'}
    assert Actor.load(out / 'before_rl').meta['timesteps'] == 0
    rng = np.random.default_rng(0)
    assert success_rate(lambda _: rng.uniform(-1, 1, 4), EPISODES, SEED, PICK_ID) == 0.0


def test_seeds_run_as_ray_tasks_and_write_one_table(tmp_path):
    out = tmp_path / 'seeds'
    trained = subprocess.run(
        [str(BIN / 'train_policy'), '--env', REACH_ID, '--timesteps', '60', '--seeds', '0', '1',
         '--num-cpus', '2', '--out', str(out), '--net', '16', '16', '--eval-every', '60',
         '--eval-episodes', '1', '--final-episodes', '1'],
        capture_output=True, text=True, timeout=400)
    assert trained.returncode == 0, trained.stderr
    table = (out / 'seeds.md').read_text()
    assert table in trained.stdout
    rows = table.splitlines()
    assert rows[0].startswith('| seed | final success (1 held-out) | best curve point | '
                              'before RL (1 held-out) | env steps | wall time |')
    assert [row.split('|')[1].strip() for row in rows[2:]] == ['0', '1']
    assert all(row.split('|')[5].strip() == '60' for row in rows[2:])
    assert (out / 'seeds.png').read_bytes().startswith(b'\x89PNG')
    for seed in (0, 1):
        assert Actor.load(out / f'seed_{seed}').meta['seed'] == seed
    # The same table from the written seeds (seeds trained one per process).
    printed = subprocess.run(
        [sys.executable, '-m', 'ur_rg2_learning.seeds', str(out / 'seed_1'), str(out / 'seed_0')],
        capture_output=True, text=True, timeout=60)
    assert printed.returncode == 0, printed.stderr
    # All but the wall time, which policy.json keeps to 0.1 s.
    assert [row.split('|')[1:6] for row in printed.stdout.splitlines()] == [
        row.split('|')[1:6] for row in rows]


def descendants(pid: int) -> set[int]:
    """Return the pids of a process's descendants (from /proc)."""
    children: dict[int, list[int]] = {}
    for stat in Path('/proc').glob('[0-9]*/stat'):
        try:
            fields = stat.read_text().rsplit(')', 1)[1].split()
        except OSError:
            continue  # ended meanwhile
        children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    found, todo = set(), [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            found.add(child)
            todo.append(child)
    return found


def test_an_interrupted_seeds_run_stops_its_ray_workers(tmp_path):
    """SIGINT to train_policy --seeds: exit 130, nothing written, no seed left computing."""
    out = tmp_path / 'seeds'
    run = subprocess.Popen(
        [str(BIN / 'train_policy'), '--env', REACH_ID, '--timesteps', '1000000', '--seeds', '0',
         '1', '--num-cpus', '2', '--out', str(out), '--net', '16', '16', '--eval-every', '100',
         '--eval-episodes', '1'], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        start_new_session=True)
    try:
        seeds_running: set[str] = set()
        for line in run.stdout:  # the seeds' curve lines come through Ray's log
            seeds_running.update(re.findall(r'seed (\d): +\d+/1000000 steps', line))
            if len(seeds_running) == 2:
                break
        assert len(seeds_running) == 2, 'the seeds did not start'
        workers = {pid for pid in descendants(run.pid)
                   if 'train_seed' in Path(f'/proc/{pid}/cmdline').read_bytes().decode(
                       errors='replace')}
        assert len(workers) == 2, workers
        run.send_signal(signal.SIGINT)
        assert run.wait(timeout=120) == 130
        assert 'train_policy: interrupted; nothing written' in run.stdout.read()
        deadline = time.monotonic() + 60
        while workers & {int(p.name) for p in Path('/proc').glob('[0-9]*')}:
            assert time.monotonic() < deadline, f'workers still running: {workers}'
            time.sleep(0.2)
        assert not out.exists()
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGKILL)
            run.wait(timeout=60)


def test_evaluate_policy_refuses_a_directory_without_a_policy(tmp_path):
    done = subprocess.run([str(BIN / 'evaluate_policy'), '--policy', str(tmp_path)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert done.stderr.startswith('evaluate_policy: no usable policy in')
    assert len(done.stderr.splitlines()) == 1


def test_cloning_only_needs_a_cloning_term():
    refused = subprocess.run(
        [str(BIN / 'train_policy'), '--env', PICK_ID, '--timesteps', '10', '--out', '/dev/null',
         '--demos', '2', '--cloning-only'], capture_output=True, text=True, timeout=120)
    assert refused.returncode == 2
    assert '--cloning-only keeps only the cloning term: give --bc' in refused.stderr


def test_cloning_only_takes_out_the_q_term_and_nothing_else():
    import torch
    from ur_rg2_learning.demonstrations import Cloning, scripted_demonstrations

    demonstrations = scripted_demonstrations(PICK_ID, 1)
    env = gym.make(PICK_ID)
    try:
        model = td3_on_pick(env, demonstrations, [16, 16], actor_lr_share=1.0, action_l2=5.0)
        model.cloning = Cloning(model, demonstrations, 1.0, alone=True)
        data = model.replay_buffer.sample(32)
        losses = []
        actor = model.actor
        actor.optimizer.step = lambda: None  # the loss's gradient is what is compared

        def gradient() -> torch.Tensor:
            actor.optimizer.zero_grad()
            model.update_actor(data, 32)
            return torch.cat([p.grad.flatten() for p in actor.parameters()])

        for alone in (True, False):
            model.cloning.alone = alone
            model.cloning._rng = np.random.default_rng(0)  # the same demonstrated batch
            losses.append(gradient())
        model.cloning.alone = True
        model.cloning._rng = np.random.default_rng(0)
        minus_q = -model.critic.q1_forward(data.observations, actor(data.observations)).mean()
        actor.optimizer.zero_grad()
        minus_q.backward()
        q_gradient = torch.cat([p.grad.flatten() for p in actor.parameters()])
        # The full update is the ablation's plus the -Q term: the filter and the penalty stay.
        assert torch.allclose(losses[1], losses[0] + q_gradient, atol=1e-5)
        assert model.cloning.q_filter
    finally:
        env.close()


def test_evaluate_policy_final_range_and_ball_noise(monkeypatch, capsys):
    from ur_rg2_learning import evaluate

    calls = []
    monkeypatch.setattr(evaluate, 'success_rate',
                        lambda actor, episodes, seed, ball_noise: calls.append(
                            (episodes, seed, ball_noise)) or 0.5)
    assert evaluate.main(['--policy', 'pick', '--final']) == 0
    assert evaluate.main(['--policy', 'pick', '--obs-noise', 'vision', '--episodes', '3']) == 0
    assert calls == [(100, evaluate.FINAL_TEST_SEED, 0.0),
                     (3, evaluate.DEFAULT_SEED, pytest.approx(0.0013))]
    assert capsys.readouterr().out == (
        'success rate 0.50 over 100 episodes (final test range 2000000-2000099)\n'
        'success rate 0.50 over 3 episodes (ball noise 1.3 mm per axis)\n')
    for wrong in (['--final', '--episodes', '5'], ['--final', '--seed', '5'],
                  ['--obs-noise', '-1']):
        with pytest.raises(SystemExit):
            evaluate.main(['--policy', 'pick', *wrong])
    monkeypatch.undo()
    assert evaluate.main(['--policy', 'reach', '--obs-noise', '1', '--episodes', '1']) == 2
    assert 'ball noise is for Pick' in capsys.readouterr().err


def test_obs_noise_is_for_pick():
    refused = subprocess.run(
        [str(BIN / 'train_policy'), '--env', REACH_ID, '--timesteps', '10', '--out', '/dev/null',
         '--obs-noise', '1'], capture_output=True, text=True, timeout=120)
    assert refused.returncode == 2 and '--obs-noise are for UrRg2Pick-v0' in refused.stderr
