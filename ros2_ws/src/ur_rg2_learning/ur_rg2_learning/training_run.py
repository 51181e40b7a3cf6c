"""One seed of train_policy: the model, the run, its curve, its export and its picture.

:func:`train_seed` trains one seed of a :class:`~ur_rg2_learning.train_config.TrainConfig`
and returns plain data (a Ray task ships it back); :func:`write_result` writes it as policy
directories (:mod:`ur_rg2_learning.actor`) and a learning curve. ``policy.json`` is the
config's policy fields and what the run measured (:func:`export`).
"""

from __future__ import annotations

from pathlib import Path
import textwrap
import time
from typing import Any

import numpy as np
from stable_baselines3 import HerReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.noise import NormalActionNoise
import torch

from ur_rg2_learning import EPISODE_STEPS, PICK_ID
from ur_rg2_learning.actor import Actor, write_atomically
from ur_rg2_learning.dataset_demos import dataset_demonstrations
from ur_rg2_learning.demonstrations import (
    Cloning,
    add_demonstrations,
    clone_actor,
    input_scaling,
    scripted_demonstrations,
)
from ur_rg2_learning.envs import make
from ur_rg2_learning.evaluate import DEFAULT_SEED, success_rate
from ur_rg2_learning.td3_cloning import ALGORITHM_CLASSES, StandardisingExtractor, TD3Cloning
from ur_rg2_learning.train_config import TrainConfig

# Curve episodes are seeded apart from training (small seeds) and from evaluate_policy's.
CURVE_SEED = 500_000
# HER settings from Gymnasium-Robotics' Fetch tasks in the rl-baselines3-zoo: HER relabels 4
# of 5 sampled transitions with goals reached later. The network and the actor's share of the
# learning rate are TrainConfig's.
HYPERPARAMETERS = {
    'learning_rate': 1e-3,  # the critic's
    'buffer_size': 1_000_000,
    'batch_size': 256,
    'gamma': 0.95,
    'tau': 0.05,
    'learning_starts': 1000,
    'action_noise': 0.2,  # standard deviation of the Gaussian exploration noise
    'her_goals': 4,
}
Curve = list[tuple[int, float, float]]  # (steps, success rate, wall seconds)


def train_seed(config: TrainConfig, seed: int) -> dict[str, Any]:
    """Train one seed; return its record and actors (plain data: Ray ships it back).

    The result has the curve, the final, before-RL and best actors (layers and meta) and
    their held-out scores.
    """
    started = time.monotonic()
    torch.manual_seed(seed)
    # The networks are small: one thread computes them fastest. With one per core, torch's
    # threads wait on each other whenever the machine is busy (the environment, other
    # processes): a 256x256 layer took 18 ms instead of 1.6 ms on the loaded 2-core machine.
    torch.set_num_threads(1)
    shares = ({'grasped_share': config.grasped_share, 'over_ball_share': config.over_ball_share}
              if config.env_id == PICK_ID else {})
    env = make(config.env_id, config.obs_noise_mm / 1000, **shares)
    extra: dict[str, Any] = {}
    if config.dataset:
        demonstrations, extra = dataset_demonstrations(
            config.dataset, env, config.camera_position, config.camera_look_at)
    else:
        demonstrations = scripted_demonstrations(config.env_id, config.demos)
    model = make_model(config, env, demonstrations, seed)
    facts = {'seed': seed, 'observation_keys': list(env.observation_space.spaces),
             'action_low': env.action_space.low.tolist(),
             'action_high': env.action_space.high.tolist(), 'cloned_before_rl': 0}
    prepare(model, config, demonstrations, extra, seed)
    run = Run(model, config, dict(facts, **extra), started)
    before_rl = run.export(0)
    run.evaluate(0)  # the actor before any reinforcement learning
    if config.timesteps:
        model.learn(config.timesteps, callback=CurveCallback(run))
    steps = model.num_timesteps
    if run.curve[-1][0] != steps:
        run.evaluate(steps)
    final = run.export(steps)
    seconds = time.monotonic() - started
    env.close()
    scores = score_held_out(config, final, before_rl, run.best, steps)
    return {
        'env': config.env_id, 'seed': seed, 'method': config.method(), 'steps': steps,
        'seconds': seconds, 'curve': run.curve, 'final_episodes': config.final_episodes,
        'final': scores['final'], 'before_rl': scores['before_rl'],
        'best_success': run.best['success'], 'best_steps': run.best['steps'],
        'actors': {'final': to_data(final), 'before_rl': to_data(before_rl),
                   'best': to_data(run.best['actor'])},
    }


def make_model(config: TrainConfig, env: Any, demonstrations: dict[str, np.ndarray],
               seed: int) -> TD3Cloning:
    """Return the config's TD3 or DDPG + HER model, inputs standardised on the demonstrations."""
    mean, std = input_scaling(config.env_id, demonstrations)
    size = env.action_space.shape[0]
    h = HYPERPARAMETERS
    timesteps = config.timesteps
    # Pick's rewards are -1 or 0 each step: its returns lie in [-1 / (1 - gamma), 0].
    q_bounds = (-1.0 / (1.0 - h['gamma']), 0.0) if config.clip_return else None
    model = ALGORITHM_CLASSES[config.algo](
        'MultiInputPolicy', env, actor_lr_share=config.actor_lr_share, q_bounds=q_bounds,
        action_l2=config.action_l2, seed=seed, learning_rate=h['learning_rate'],
        buffer_size=min(h['buffer_size'], timesteps + len(demonstrations.get('action', []))),
        batch_size=h['batch_size'], gamma=h['gamma'], tau=h['tau'],
        # HER samples whole episodes: the first must have ended before the first update.
        learning_starts=min(h['learning_starts'],
                            max(timesteps // 2, EPISODE_STEPS[config.env_id])),
        action_noise=NormalActionNoise(np.zeros(size), h['action_noise'] * np.ones(size)),
        replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs={'n_sampled_goal': h['her_goals'],
                              'goal_selection_strategy': 'future'},
        policy_kwargs={'net_arch': list(config.net_arch),
                       'features_extractor_class': StandardisingExtractor,
                       'features_extractor_kwargs': {'mean': mean, 'std': std}},
        verbose=0)
    # Without a logger of its own, each learn() makes an empty /tmp/SB3-<time> folder.
    model.set_logger(Logger(None, []))
    return model


def prepare(model: TD3Cloning, config: TrainConfig, demonstrations: dict[str, np.ndarray],
            extra: dict[str, Any], seed: int) -> None:
    """Put the demonstrations in, clone a data set's, set the cloning term, warm the critic.

    A data set's cloning adds its facts to ``extra`` (policy.json's).
    """
    add_demonstrations(model.replay_buffer, demonstrations)
    if config.dataset and config.bc_epochs:
        loss, took = clone_actor(model, demonstrations, config.bc_epochs, seed)
        extra['cloned_before_rl'] = len(demonstrations['action'])
        extra['cloning_loss'] = round(loss, 5)
        print(f"cloned {len(demonstrations['action'])} steps of "
              f"{extra['dataset']['episodes_used']} episodes, {config.bc_epochs} epochs: "
              f'loss {loss:.4f} in {took:.0f} s', flush=True)
    if config.bc:
        model.cloning = Cloning(model, demonstrations, config.bc, config.q_filter,
                                alone=config.cloning_only, fade=config.bc_fade)
    model.warm_up_critic(config.critic_warmup)


class Run:
    """A run's learning curve: the deterministic actor's success every so many steps.

    The best point's actor is kept too (the latest of equals: it has learned the longest);
    the run's result is the final actor, not this one.
    """

    def __init__(self, model: TD3Cloning, config: TrainConfig, facts: dict[str, Any],
                 started: float) -> None:
        self.model = model
        self.config = config
        self.facts = facts  # policy.json's facts of the run beside the config's
        self.started = started
        self.curve: Curve = []
        self.best: dict[str, Any] = {}

    def export(self, steps: int) -> Actor:
        """Return the model's actor now, as after ``steps`` environment steps."""
        return export(self.model, self.config, self.facts, steps,
                      time.monotonic() - self.started, self.curve)

    def evaluate(self, steps: int) -> None:
        """Add a point to the curve (and keep the actor if it is the best) and print it."""
        config = self.config
        actor = self.export(steps)
        rate = success_rate(actor, config.eval_episodes, CURVE_SEED, config.env_id,
                            config.obs_noise_mm / 1000)
        if not self.curve or rate >= max(point[1] for point in self.curve):
            self.best.update(actor=actor, steps=steps, success=rate)
        seconds = time.monotonic() - self.started
        self.curve.append((steps, rate, seconds))
        cloned = (f'  cloned {self.model.cloning.share:4.2f}'
                  if config.bc and config.q_filter else '')
        print(f'{config.env_id} {config.algo} seed {self.facts["seed"]}: '
              f'{steps:>8d}/{config.timesteps} steps  success {rate:4.2f}  {seconds:6.0f} s'
              f'{cloned}', flush=True)


class CurveCallback(BaseCallback):
    """Measure the run's curve every ``eval_every`` steps; stop at its wall-time bound.

    :param run: the run whose curve this measures
    """

    def __init__(self, run: Run) -> None:
        super().__init__()
        self.run = run
        config = run.config
        self.every = config.eval_every or max(config.timesteps // 20, 1)
        self.deadline = (run.started + 60.0 * config.minutes if config.minutes
                         else float('inf'))

    def _on_step(self) -> bool:
        if self.num_timesteps % self.every == 0:
            self.run.evaluate(self.num_timesteps)
        return time.monotonic() < self.deadline


def score_held_out(config: TrainConfig, final: Actor, before_rl: Actor, best: dict[str, Any],
                   steps: int) -> dict[str, float]:
    """Score the final and the before-RL actor on held-out episodes; note it in each meta."""
    episodes = config.final_episodes
    noise = config.obs_noise_mm / 1000
    scores = {name: (success_rate(actor, episodes, DEFAULT_SEED, ball_noise=noise)
                     if episodes else float('nan'))
              for name, actor in (('final', final), ('before_rl', before_rl))
              if name == 'final' or steps}
    scores.setdefault('before_rl', scores['final'])  # no RL step: the same actor
    for actor in (final, before_rl, best['actor']):
        actor.meta['held_out'] = {'episodes': episodes, 'seed': DEFAULT_SEED,
                                  'obs_noise_mm': config.obs_noise_mm,
                                  'final_success': scores['final'],
                                  'before_rl_success': scores['before_rl']}
    best['actor'].meta['best_of_curve'] = {'steps': best['steps'], 'success': best['success']}
    return scores


def export(model: TD3Cloning, config: TrainConfig, facts: dict[str, Any], steps: int,
           seconds: float, curve: Curve) -> Actor:
    """Return the model's actor as a NumPy :class:`Actor` with its training record.

    ``policy.json`` holds the config's policy fields, ``facts`` (the seed, the observation's
    keys, the action bounds, ...) and what the run measured.
    """
    # Stable-Baselines3's MultiInputPolicy flattens the observation dict in the space's order;
    # the fixed standardisation folds into the first layer.
    linear = [layer for layer in model.actor.mu if hasattr(layer, 'weight')]
    layers = [(layer.weight.detach().cpu().numpy().astype(np.float64),
               layer.bias.detach().cpu().numpy().astype(np.float64)) for layer in linear]
    extractor = model.actor.features_extractor
    mean = extractor.mean.cpu().numpy().astype(np.float64)
    std = extractor.std.cpu().numpy().astype(np.float64)
    weight, bias = layers[0]
    layers[0] = (weight / std, bias - (weight / std) @ mean)
    meta = {
        **config.policy_fields(),
        'method': config.method(),
        **facts,
        'episode_steps': EPISODE_STEPS[config.env_id],
        'timesteps': steps,
        'train_seconds': round(seconds, 1),
        'hyperparameters': dict(HYPERPARAMETERS, net_arch=list(config.net_arch),
                                actor_lr_share=config.actor_lr_share,
                                learning_starts=model.learning_starts),
        'rl_updates': int(model._n_updates),
        'curve': [{'steps': s, 'success': r, 'seconds': round(t, 1)} for s, r, t in curve],
    }
    return Actor(layers, meta)


def to_data(actor: Actor) -> dict[str, Any]:
    """Return an actor as plain data (layers, meta)."""
    return {'layers': actor.layers, 'meta': actor.meta}


def summary(result: dict[str, Any], out: Path) -> str:
    """Return the line a finished seed prints."""
    return (f"{result['env']} seed {result['seed']}: {result['steps']} steps in "
            f"{result['seconds']:.0f} s; final success {result['final']:.2f}, before RL "
            f"{result['before_rl']:.2f} over {result['final_episodes']} held-out episodes; "
            f'wrote {out}')


def write_result(result: dict[str, Any], out: Path) -> None:
    """Write a seed's actors (final into ``out``, before_rl/, best/) and its curve picture."""
    out.mkdir(parents=True, exist_ok=True)
    actors = result['actors']
    Actor(**actors['final']).save(out)
    Actor(**actors['before_rl']).save(out / 'before_rl')
    Actor(**actors['best']).save(out / 'best')
    plot_curves({result['seed']: result['curve']}, f"{result['env']}, {result['method']}",
                out / 'learning_curve.png')


def plot_curves(curves: dict[int, Curve], title: str, path: Path) -> None:
    """Draw each seed's success rate over environment steps into ``path``."""
    import matplotlib
    matplotlib.use('Agg')
    from matplotlib import pyplot

    figure, axes = pyplot.subplots(figsize=(6.4, 3.6), dpi=100)
    longest = 0.0
    for seed, curve in sorted(curves.items()):
        steps, rates, seconds = zip(*curve)
        longest = max(longest, seconds[-1])
        axes.plot(steps, rates, marker='o', markersize=3, label=f'seed {seed}')
    axes.set_xlabel('environment steps')
    axes.set_ylabel('success rate')
    axes.set_ylim(-0.02, 1.02)
    axes.grid(alpha=0.3)
    if len(curves) > 1:
        axes.legend(fontsize=8)
    axes.set_title(textwrap.fill(f'{title}: up to {longest / 60:.1f} min of training', 90),
                   fontsize=8)
    figure.tight_layout()
    write_atomically(path, lambda f: figure.savefig(f, format='png'))
    pyplot.close(figure)
