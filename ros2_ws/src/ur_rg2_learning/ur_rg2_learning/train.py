"""``train_policy``: train DDPG (or TD3; Stable-Baselines3, with HER) on one environment.

For Pick, ``--demos N`` puts N scripted pick episodes into the replay buffer and ``--bc W``
adds behaviour cloning on them to every actor update (Nair et al. 2018): the squared
distance to the demonstrated actions where the critic rates them above the actor's own (the
Q-filter), weighted W times the batch's mean |Q| (as TD3+BC); ``--pretrain N`` clones them N
updates before the first environment step.

Shows a progress bar (rate, ETA) and writes to ``--out``: the actor for the run path
(``actor.npz`` + ``policy.json``, see :mod:`ur_rg2_learning.actor`), the whole
Stable-Baselines3 model (``model.zip``, to train on) and ``learning_curve.png``: the
deterministic policy's success rate on ``--eval-episodes`` fresh episodes every
``--eval-every`` steps; ``best/`` the actor of the curve's best point. Needs the learning
set-up (``scripts/bootstrap requirements-learning.txt``).
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys
import time

import gymnasium as gym
import numpy as np
from ur_rg2_vision.dataset import Progress

from ur_rg2_learning import EPISODE_STEPS, PICK_ID, REACH_ID
from ur_rg2_learning.actor import Actor, write_atomically
from ur_rg2_learning.evaluate import success_rate

# Curve episodes are seeded apart from training (small seeds) and from evaluate_policy's.
CURVE_SEED = 500_000
DEMO_SEED = 700_000  # and the demonstrations' episodes, apart from both
DEMO_HOLD_STEPS = 10  # steps of each demonstration after the ball is lifted
ALGORITHMS = {'ddpg': 'DDPG', 'td3': 'TD3'}
# Observations (m, m/s) times this into the networks (the shipped Reach policy: 1).
INPUT_SCALE = {REACH_ID: 1.0, PICK_ID: 10.0}
# DDPG + HER settings (Gymnasium-Robotics' Fetch tasks in the rl-baselines3-zoo, with a
# wider network): HER relabels 4 of 5 sampled transitions with goals reached later.
HYPERPARAMETERS = {
    'learning_rate': 1e-3,
    'buffer_size': 1_000_000,
    'batch_size': 256,
    'gamma': 0.95,
    'tau': 0.05,
    'learning_starts': 1000,
    'net_arch': [256, 256],
    'action_noise': 0.2,  # standard deviation of the Gaussian exploration noise
    'her_goals': 4,
}


def main(argv: list[str] | None = None) -> int:
    """Train, export, plot; exit code 0, 2 when the learning set-up is missing."""
    parser = argparse.ArgumentParser(prog='train_policy', description=__doc__.split('\n')[0])
    parser.add_argument('--env', required=True, choices=[REACH_ID, PICK_ID])
    parser.add_argument('--algo', default='ddpg', choices=list(ALGORITHMS))
    parser.add_argument('--timesteps', type=int, required=True, help='environment steps')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--out', required=True, help='directory to write the policy to')
    parser.add_argument('--eval-every', type=int, default=0,
                        help='steps between learning-curve points (default: timesteps / 20)')
    parser.add_argument('--eval-episodes', type=int, default=20,
                        help='episodes per learning-curve point (20)')
    parser.add_argument('--demos', type=int, default=0,
                        help=f'{PICK_ID} only: scripted pick episodes put into the replay '
                        'buffer before training (0)')
    parser.add_argument('--bc', type=float, default=0.0,
                        help='weight of the behaviour-cloning updates on the demonstrations '
                        '(0: none; needs --demos)')
    parser.add_argument('--no-q-filter', dest='q_filter', action='store_false',
                        help='clone every demonstrated step, not only those the critic '
                        'rates above the actor')
    parser.add_argument('--pretrain', type=int, default=0,
                        help='behaviour-cloning updates of the actor before the first step '
                        '(0; needs --demos)')
    args = parser.parse_args(argv)
    if args.timesteps < 1 or args.eval_episodes < 1 or min(args.demos, args.bc,
                                                           args.pretrain) < 0:
        parser.error('--timesteps and --eval-episodes must be positive, --demos, --bc and '
                     '--pretrain not negative')
    if args.demos and args.env != PICK_ID:
        parser.error(f'--demos is for {PICK_ID}')
    if (args.bc or args.pretrain) and not args.demos:
        parser.error('--bc and --pretrain clone the demonstrations: give --demos')
    try:
        from stable_baselines3 import DDPG, TD3, HerReplayBuffer
        from stable_baselines3.common.callbacks import BaseCallback
        from stable_baselines3.common.noise import NormalActionNoise
        import torch
    except ImportError as error:
        print(f'train_policy needs the learning set-up ({error}): run '
              '`scripts/bootstrap requirements-learning.txt`', file=sys.stderr)
        return 2

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    every = args.eval_every or max(args.timesteps // 20, 1)
    torch.manual_seed(args.seed)
    # DDPG's networks are small: one thread computes them fastest. With one per core, torch's
    # threads wait on each other whenever the machine is busy (the environment, other
    # processes): a 256x256 layer took 18 ms instead of 1.6 ms on the loaded 2-core machine.
    torch.set_num_threads(1)
    env = gym.make(args.env)
    size = env.action_space.shape[0]
    h = HYPERPARAMETERS
    algorithm = with_cloning({'ddpg': DDPG, 'td3': TD3}[args.algo])
    model = algorithm(
        'MultiInputPolicy', env, seed=args.seed, learning_rate=h['learning_rate'],
        buffer_size=min(h['buffer_size'], args.timesteps + args.demos * EPISODE_STEPS[args.env]),
        batch_size=h['batch_size'],
        gamma=h['gamma'], tau=h['tau'], learning_starts=min(h['learning_starts'],
                                                            args.timesteps // 2),
        action_noise=NormalActionNoise(np.zeros(size), h['action_noise'] * np.ones(size)),
        replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs={'n_sampled_goal': h['her_goals'],
                              'goal_selection_strategy': 'future'},
        policy_kwargs={'net_arch': h['net_arch'],
                       'features_extractor_class': scaled_extractor(),
                       'features_extractor_kwargs': {'scale': INPUT_SCALE[args.env]}},
        verbose=0)
    curve: list[tuple[int, float, float]] = []  # (steps, success rate, wall seconds)
    started = time.monotonic()
    demonstrations = add_demonstrations(model.replay_buffer, args.env, args.demos)
    if args.bc or args.pretrain:
        model.cloning = Cloning(model, demonstrations, args.bc, args.q_filter)
        model.cloning.pretrain(args.pretrain, h['batch_size'])

    # The data set command's bar (rate, ETA) on a terminal; a line per curve point otherwise.
    progress = Progress(args.timesteps, every=every)

    def evaluate(steps: int) -> None:
        actor = export(model, args, env, time.monotonic() - started, curve)
        rate = success_rate(actor, args.eval_episodes, CURVE_SEED, args.env)
        if not curve or rate >= max(point[1] for point in curve):
            # DDPG's success can collapse and recover from one point to the next: the best
            # point's actor is kept too (the latest of equals: it has learned the longest).
            actor.meta['best_of_curve'] = {'steps': steps, 'success': rate}
            actor.save(out / 'best')
        curve.append((steps, rate, time.monotonic() - started))
        if progress.tty:
            progress.stream.write('\n')
        print(f'{args.env} {args.algo}: {steps:>8d}/{args.timesteps} steps  success {rate:4.2f}  '
              f'{time.monotonic() - started:6.0f} s', flush=True)

    class Steps(BaseCallback):
        def _on_step(self) -> bool:
            progress.advance()
            if self.num_timesteps % every == 0:
                evaluate(self.num_timesteps)
            return True

    if args.pretrain:
        evaluate(0)  # the cloned policy, before any reinforcement learning
    try:
        model.learn(args.timesteps, callback=Steps())
    finally:
        progress.close()
    if not curve or curve[-1][0] != args.timesteps:
        evaluate(args.timesteps)
    seconds = time.monotonic() - started
    export(model, args, env, seconds, curve).save(out)
    model.save(out / 'model.zip')
    method = f'{ALGORITHMS[args.algo]} + HER' + (
        f' + {args.demos} scripted demos' if args.demos else '') + (
        f' + BC {args.bc:g}' if args.bc else '') + (
        f', {args.pretrain} BC updates first' if args.pretrain else '')
    plot_curve(curve, f'{args.env}, {method}', out / 'learning_curve.png')
    env.close()
    print(f'{args.env}: trained {args.timesteps} steps in {seconds:.0f} s; success '
          f'{curve[-1][1]:.2f} over {args.eval_episodes} episodes; wrote {out}')
    return 0


def add_demonstrations(buffer, env_id: str, episodes: int) -> dict[str, np.ndarray]:
    """Put ``episodes`` of the scripted pick into the replay buffer, as if it had acted.

    Each episode ends DEMO_HOLD_STEPS steps after the ball is first lifted (cut there, as by
    a time limit): the whole 100 steps would be mostly the ball held still, and a policy
    cloned from them learns to stand still anywhere. Returns them as arrays: each observation
    key's values and ``action``, one row a step.
    """
    from ur_rg2_learning.scripted import pick_action

    env = gym.make(env_id)
    steps: dict[str, list[np.ndarray]] = {}
    try:
        for episode in range(episodes):
            observation, _ = env.reset(seed=DEMO_SEED + episode)
            done, held = False, 0
            while not done:
                action = pick_action(observation)
                for key, value in (*observation.items(), ('action', action)):
                    steps.setdefault(key, []).append(value)
                following, reward, terminated, truncated, info = env.step(action)
                held += bool(info['is_success'])
                truncated = truncated or held > DEMO_HOLD_STEPS
                done = terminated or truncated
                # Stable-Baselines3's flag for an episode cut by its time limit.
                info = dict(info, **{'TimeLimit.truncated': truncated and not terminated})
                buffer.add({key: value[None] for key, value in observation.items()},
                           {key: value[None] for key, value in following.items()},
                           action[None], np.array([reward]), np.array([done]), [info])
                observation = following
    finally:
        env.close()
    return {key: np.array(values) for key, values in steps.items()}


def scaled_extractor() -> type:
    """Return Stable-Baselines3's dict extractor with its output multiplied by ``scale``.

    Pick's policy tells a grasp from a miss by millimetres: inputs in decimetres rather than
    metres let the network see them. The export folds the scale into the first layer.
    """
    from stable_baselines3.common.torch_layers import CombinedExtractor

    class ScaledExtractor(CombinedExtractor):
        def __init__(self, observation_space, scale: float = 1.0) -> None:
            super().__init__(observation_space)
            self.scale = scale

        def forward(self, observations):
            return super().forward(observations) * self.scale

    return ScaledExtractor


def with_cloning(algorithm: type) -> type:
    """Return a subclass of a Stable-Baselines3 TD3-family class running ``model.cloning``.

    Its actor updates then minimise the algorithm's actor loss plus the cloning loss: the
    cloning gradient is added to the actor's before each step of its optimiser.
    """

    class WithCloning(algorithm):
        cloning: Cloning | None = None

        def train(self, gradient_steps: int, batch_size: int = 100) -> None:
            if self.cloning is None:
                super().train(gradient_steps, batch_size)
                return
            optimizer = self.actor.optimizer
            step = optimizer.step

            def step_with_cloning(*args, **kwargs):
                self.cloning.backward(batch_size, critic=True)
                return step(*args, **kwargs)

            optimizer.step = step_with_cloning
            try:
                super().train(gradient_steps, batch_size)
            finally:
                del optimizer.step

        def _excluded_save_params(self) -> list[str]:
            return [*super()._excluded_save_params(), 'cloning']

    WithCloning.__name__ = algorithm.__name__
    return WithCloning


class Cloning:
    """Behaviour cloning of demonstrations into a TD3-family actor (Nair et al., 2018).

    Each update draws a batch of demonstrated steps; the loss is the squared distance from the
    actor's actions to the demonstrated ones, on the steps where the critic values the
    demonstrated action above the actor's (the Q-filter, so that the actor may outgrow a
    demonstrator the critic finds worse), times ``weight`` and the batch's mean |Q| (as
    TD3+BC, Fujimoto and Gu 2021, balances it against the actor loss -Q, whatever the scale
    of the returns).
    """

    def __init__(self, model, demonstrations: dict[str, np.ndarray], weight: float,
                 q_filter: bool = True) -> None:
        import torch

        self._torch = torch
        self.model = model
        self.weight = weight
        self.q_filter = q_filter
        device = model.device
        self.actions = torch.as_tensor(demonstrations['action'], device=device)
        self.observations = {key: torch.as_tensor(demonstrations[key], device=device)
                             for key in model.observation_space.spaces}
        self._rng = np.random.default_rng(model.seed)

    def pretrain(self, updates: int, batch_size: int) -> None:
        """Clone the demonstrations ``updates`` times (no critic yet: plain cloning)."""
        optimizer = self.model.actor.optimizer
        for _ in range(updates):
            optimizer.zero_grad()
            self.backward(batch_size, critic=False)
            optimizer.step()
        self.model.actor_target.load_state_dict(self.model.actor.state_dict())

    def backward(self, batch_size: int, critic: bool) -> float:
        """Add the gradient of the cloning loss on a batch to the actor's; return the loss.

        Without a ``critic`` (before there is one) the loss is the plain squared error.
        """
        torch = self._torch
        model = self.model
        rows = torch.as_tensor(self._rng.integers(0, len(self.actions), batch_size))
        observations = {key: value[rows] for key, value in self.observations.items()}
        demonstrated = self.actions[rows]
        actions = model.actor(observations)
        error = ((actions - demonstrated) ** 2).sum(dim=1)
        if critic:
            with torch.no_grad():
                q_demonstrated = model.critic.q1_forward(observations, demonstrated)
                q_actor = model.critic.q1_forward(observations, actions)
                better = (q_demonstrated > q_actor).float().squeeze(1)
                scale = self.weight * q_actor.abs().mean()
            loss = scale * (error * better if self.q_filter else error).mean()
        else:
            loss = error.mean()
        loss.backward()
        return loss.item()


def export(model, args: argparse.Namespace, env: gym.Env, seconds: float,
           curve: list[tuple[int, float, float]]) -> Actor:
    """Return the model's actor as a NumPy :class:`Actor` with its training record."""
    # Stable-Baselines3's MultiInputPolicy flattens the observation dict in the space's order.
    network = model.actor.mu
    linear = [layer for layer in network if hasattr(layer, 'weight')]
    layers = [(layer.weight.detach().cpu().numpy().copy(),
               layer.bias.detach().cpu().numpy().copy()) for layer in linear]
    layers[0] = (layers[0][0] * model.actor.features_extractor.scale, layers[0][1])
    meta = {
        'env_id': args.env,
        'algo': args.algo,
        'observation_keys': list(env.observation_space.spaces),
        'action_low': env.action_space.low.tolist(),
        'action_high': env.action_space.high.tolist(),
        'episode_steps': EPISODE_STEPS[args.env],
        'timesteps': args.timesteps,
        'seed': args.seed,
        'demos': args.demos,
        'bc': args.bc,
        'q_filter': args.q_filter,
        'pretrain': args.pretrain,
        'train_seconds': round(seconds, 1),
        'hyperparameters': dict(HYPERPARAMETERS, input_scale=INPUT_SCALE[args.env]),
        'curve': [{'steps': s, 'success': r, 'seconds': round(t, 1)} for s, r, t in curve],
    }
    return Actor(layers, meta)


def plot_curve(curve: list[tuple[int, float, float]], title: str, path: Path) -> None:
    """Draw success rate over environment steps (wall time on the top axis) into ``path``."""
    import matplotlib
    matplotlib.use('Agg')
    from matplotlib import pyplot

    steps, rates, seconds = zip(*curve)
    figure, axes = pyplot.subplots(figsize=(6.4, 3.6), dpi=100)
    axes.plot(steps, rates, marker='o', markersize=3)
    axes.set_xlabel('environment steps')
    axes.set_ylabel('success rate')
    axes.set_ylim(-0.02, 1.02)
    axes.grid(alpha=0.3)
    axes.set_title(f'{title}: {seconds[-1] / 60:.1f} min of training', fontsize=10)
    figure.tight_layout()
    write_atomically(path, lambda f: figure.savefig(f, format='png'))
    pyplot.close(figure)


if __name__ == '__main__':
    sys.exit(main())
