"""``train_policy``: train TD3 or DDPG (Stable-Baselines3, with HER) on one environment.

For Pick, ``--demos N`` puts N scripted pick episodes into the replay buffer (data only: no
cloning before the first update, so the actor that starts reinforcement learning is the
untrained network), ``--bc W`` adds a Q-filtered behaviour-cloning term on them to every
actor update (Nair et al. 2018: the squared distance to the demonstrated actions where the
critic rates them above the actor's own, weighted W times the batch's mean |Q| as TD3+BC),
``--critic-warmup N`` trains the critic N updates on the demonstrations before the actor
moves, ``--grasped-share S`` starts that share of the training episodes with the ball already
between the fingers (Fetch's trick) and ``--over-ball-share S`` with the open fingers round
or over it (evaluation episodes never start either way). ``--clip-return`` clips the critic's
targets to the returns Pick's rewards allow and ``--action-l2 W`` penalises the actor's moves
(both as the HER baselines do). ``--obs-noise MM`` observes the ball with Gaussian noise of
MM mm per axis in training and in its evaluations (:class:`ur_rg2_learning.envs.BallNoise`:
in the graph, the vision node's estimate takes the true ball's place). Inputs are
standardised with the demonstrations' (or a few random episodes') mean and deviation, fixed
for the run.

``--dataset DIR`` trains Pick from a LeRobot data set recorded in the graph
(:mod:`ur_rg2_learning.dataset_demos`): ``--bc-epochs`` of behaviour cloning of its steps into
the actor, then, with ``--finetune-steps N``, N steps of the same TD3 + HER training with the
data set's steps in the replay buffer in place of the scripted demonstrations (``--bc`` and
the other options as above).

``--seed N`` trains one seed in this process; ``--seeds A B ...`` trains each as a Ray task
(a local Ray with ``--num-cpus`` by default, an existing cluster with ``--address``) and writes
one table and one picture of the seeds' curves. ``--minutes`` bounds each seed's wall time:
the run ends there, and the policy it ends with is the one written.

Writes to ``--out`` (per seed ``seed_N/`` with ``--seeds``): the final actor for the run path
(``actor.npz`` + ``policy.json``, see :mod:`ur_rg2_learning.actor`), ``before_rl/`` the actor
before the first update, ``best/`` the actor of the curve's best point, and
``learning_curve.png``: the deterministic policy's success on ``--eval-episodes`` fresh
episodes every ``--eval-every`` steps. ``--final-episodes`` held-out episodes (evaluate_policy's)
score the final and the before-RL actor. Needs the learning set-up
(``scripts/bootstrap requirements-learning.txt``).
"""

from __future__ import annotations

import argparse
from pathlib import Path
import shlex
import sys
import textwrap
import time
from typing import Any

import gymnasium as gym
import numpy as np

from ur_rg2_learning import EPISODE_STEPS, PICK_ID, REACH_ID
from ur_rg2_learning.actor import Actor, write_atomically
from ur_rg2_learning.dataset_demos import (
    CAMERA_LOOK_AT,
    CAMERA_POSITION,
    DatasetError,
    dataset_demonstrations,
    read_dataset,
)
from ur_rg2_learning.envs import make
from ur_rg2_learning.evaluate import DEFAULT_SEED, noise_mm, success_rate

# Curve episodes are seeded apart from training (small seeds) and from evaluate_policy's.
CURVE_SEED = 500_000
DEMO_SEED = 700_000  # and the demonstrations' episodes, apart from both
DEMO_HOLD_STEPS = 10  # steps of each demonstration after the ball is lifted
ALGORITHMS = {'ddpg': 'DDPG', 'td3': 'TD3'}
# HER settings from Gymnasium-Robotics' Fetch tasks in the rl-baselines3-zoo: HER relabels 4
# of 5 sampled transitions with goals reached later.
HYPERPARAMETERS = {
    'learning_rate': 1e-3,  # the critic's
    'actor_lr_share': 0.1,  # the actor learns this much slower than the critic
    'buffer_size': 1_000_000,
    'batch_size': 256,
    'gamma': 0.95,
    'tau': 0.05,
    'learning_starts': 1000,
    'net_arch': [256, 256],
    'action_noise': 0.2,  # standard deviation of the Gaussian exploration noise
    'her_goals': 4,
}
INPUT_STD_FLOOR = 0.05  # m, m/s: the least deviation an input is standardised with
NORMALISE_EPISODES = 10  # random episodes that set the input scaling when there are no demos
CLONING_LR = 1e-3  # --dataset: Adam's learning rate for the cloning
CLONING_BOUND = 0.9  # --dataset: the cloned actions are clipped to this, short of +-1
DATASET_BC_EPOCHS = 300  # --dataset: passes of behaviour cloning over the data set's steps


def parser() -> argparse.ArgumentParser:
    """Return train_policy's argument parser."""
    p = argparse.ArgumentParser(prog='train_policy', description=__doc__.split('\n')[0])
    p.add_argument('--env', choices=[REACH_ID, PICK_ID],
                   help=f'the environment (required; {PICK_ID} with --dataset)')
    p.add_argument('--algo', default='td3', choices=list(ALGORITHMS))
    p.add_argument('--timesteps', type=int,
                   help='environment steps (at most; required unless --dataset)')
    p.add_argument('--dataset', metavar='DIR',
                   help=f"{PICK_ID} from a LeRobot data set (to_lerobot's): behaviour cloning "
                   'of its steps, then --finetune-steps of TD3 + HER with them in the buffer')
    p.add_argument('--bc-epochs', type=int, default=DATASET_BC_EPOCHS,
                   help='with --dataset: epochs of behaviour cloning (%(default)s)')
    p.add_argument('--finetune-steps', type=int, default=0,
                   help='with --dataset: environment steps of TD3 + HER after the cloning (0)')
    p.add_argument('--camera-position', type=float, nargs=3, metavar=('X', 'Y', 'Z'),
                   default=CAMERA_POSITION, help="with --dataset: the recording's camera_position "
                   "(world, m; the sim's default %(default)s)")
    p.add_argument('--camera-look-at', type=float, nargs=3, metavar=('X', 'Y', 'Z'),
                   default=CAMERA_LOOK_AT, help="with --dataset: the recording's camera_look_at "
                   '(%(default)s)')
    seeds = p.add_mutually_exclusive_group()
    seeds.add_argument('--seed', type=int, default=0, help='one seed, in this process (0)')
    seeds.add_argument('--seeds', type=int, nargs='+',
                       help='several seeds, each a Ray task (writes seed_N/ for each)')
    p.add_argument('--out', required=True, help='directory to write the policy to')
    p.add_argument('--minutes', type=float, default=0.0,
                   help='wall time per seed at most (0: no bound); the run ends there')
    p.add_argument('--eval-every', type=int, default=0,
                   help='steps between learning-curve points (default: timesteps / 20)')
    p.add_argument('--eval-episodes', type=int, default=20,
                   help='episodes per learning-curve point (20)')
    p.add_argument('--final-episodes', type=int, default=100,
                   help='held-out episodes scoring the final and the before-RL actor (100)')
    p.add_argument('--demos', type=int, default=0,
                   help=f'{PICK_ID} only: scripted pick episodes put into the replay buffer')
    p.add_argument('--bc', type=float, default=0.0,
                   help='weight of the behaviour-cloning term in the actor updates (0: none; '
                   'needs --demos)')
    p.add_argument('--bc-fade', type=int, default=0,
                   help='environment steps over which the cloning weight falls linearly to 0 '
                   '(0: it stays); after them the actor learns from the critic alone')
    p.add_argument('--no-q-filter', dest='q_filter', action='store_false',
                   help='clone every demonstrated step, not only those the critic rates above '
                   'the actor')
    p.add_argument('--cloning-only', action='store_true',
                   help="ablation: the algorithm's -Q term taken out of the actor updates, "
                   'nothing else (the Q-filter, unless --no-q-filter, and --action-l2 stay; '
                   'the critic still learns; needs --bc)')
    p.add_argument('--critic-warmup', type=int, default=0,
                   help='critic updates on the demonstrations before the first step (0)')
    p.add_argument('--grasped-share', type=float, default=0.0,
                   help=f'{PICK_ID} only: share of training episodes that start with the ball '
                   'between the fingers (0)')
    p.add_argument('--over-ball-share', type=float, default=0.0,
                   help=f'{PICK_ID} only: share of training episodes that start with the open '
                   'fingers round or over the ball (0)')
    p.add_argument('--clip-return', action='store_true',
                   help=f"{PICK_ID} only: clip the critic's targets to the returns its rewards "
                   '(-1 or 0) allow, as the HER baselines do')
    p.add_argument('--action-l2', type=float, default=0.0,
                   help="weight of a penalty on the actor's squared moves (0; the HER "
                   'baselines use 1)')
    p.add_argument('--obs-noise', type=noise_mm, default=0.0, metavar='MM',
                   help=f"{PICK_ID} only: Gaussian noise on the observed ball, mm per axis, or "
                   "'vision' (training and its evaluations; 0: none)")
    p.add_argument('--net', type=int, nargs='+', default=HYPERPARAMETERS['net_arch'],
                   help='hidden layer sizes of actor and critic (%(default)s)')
    p.add_argument('--actor-lr-share', type=float, default=HYPERPARAMETERS['actor_lr_share'],
                   help="the actor's learning rate as a share of the critic's (%(default)s)")
    p.add_argument('--num-cpus', type=int, default=None,
                   help='with --seeds: CPUs of the local Ray (default: all)')
    p.add_argument('--address', default=None,
                   help='with --seeds: an existing Ray cluster (auto or HOST:PORT)')
    return p


def main(argv: list[str] | None = None) -> int:
    """Train, export, plot; exit code 0, 2 without the learning set-up, 130 on Ctrl-C."""
    p = parser()
    args = p.parse_args(argv)
    if args.dataset is not None:
        if args.env not in (None, PICK_ID) or args.timesteps is not None or args.demos \
                or args.seeds:
            p.error(f'--dataset trains {PICK_ID}, one --seed, for --finetune-steps: no --env '
                    'Reach, --timesteps, --demos or --seeds with it')
        if args.bc_epochs < 0 or args.finetune_steps < 0 or not (
                args.bc_epochs or args.finetune_steps):
            p.error('--bc-epochs and --finetune-steps must not be negative, nor both 0')
        args.env, args.timesteps = PICK_ID, args.finetune_steps
    elif args.env is None or args.timesteps is None:
        p.error('--env and --timesteps are required (or --dataset)')
    elif args.timesteps < 1:
        p.error('--timesteps must be positive')
    if args.eval_episodes < 1 or args.final_episodes < 0 or min(
            args.demos, args.bc, args.critic_warmup, args.minutes, args.bc_fade) < 0:
        p.error('--timesteps and --eval-episodes must be positive; --demos, --bc, '
                '--critic-warmup, --minutes and --final-episodes not negative')
    if (args.demos or args.grasped_share or args.over_ball_share
            or args.clip_return or args.obs_noise) and args.env != PICK_ID:
        p.error(f'--demos, --grasped-share, --over-ball-share, --clip-return and --obs-noise '
                f'are for {PICK_ID}')
    if (args.bc or args.critic_warmup) and not (args.demos or args.dataset):
        p.error('--bc and --critic-warmup train on the demonstrations: give --demos or '
                '--dataset')
    if args.cloning_only and not args.bc:
        p.error('--cloning-only keeps only the cloning term: give --bc')
    if not (0.0 <= args.grasped_share and 0.0 <= args.over_ball_share
            and args.grasped_share + args.over_ball_share <= 1.0):
        p.error('--grasped-share and --over-ball-share are shares: 0 to 1, together too')
    if args.action_l2 < 0:
        p.error('--action-l2 must not be negative')
    if args.dataset is not None:
        try:
            read_dataset(args.dataset)  # its errors now, before any training
        except DatasetError as error:
            print(f'train_policy: {error}', file=sys.stderr)
            return 2
    try:
        import stable_baselines3  # noqa: F401
        import torch  # noqa: F401
    except ImportError as error:
        print(f'train_policy needs the learning set-up ({error}): run '
              '`scripts/bootstrap requirements-learning.txt`', file=sys.stderr)
        return 2
    config = {key: value for key, value in vars(args).items()
              if key not in ('seeds', 'seed', 'num_cpus', 'address', 'out')}
    config['command'] = shlex.join(['train_policy', *(sys.argv[1:] if argv is None else argv)])
    out = Path(args.out)
    try:
        if args.seeds is None:
            result = train_seed(config, args.seed)
            write_result(result, out)
            print(summary(result, out))
            return 0
        from ur_rg2_learning.seeds import run_seeds

        return run_seeds(config, args.seeds, out, args.num_cpus, args.address)
    except DatasetError as error:
        print(f'train_policy: {error}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'train_policy: interrupted; nothing written to {out}', file=sys.stderr)
        return 130


def summary(result: dict[str, Any], out: Path) -> str:
    """Return the line a finished seed prints."""
    return (f"{result['env']} seed {result['seed']}: {result['steps']} steps in "
            f"{result['seconds']:.0f} s; final success {result['final']:.2f}, before RL "
            f"{result['before_rl']:.2f} over {result['final_episodes']} held-out episodes; "
            f'wrote {out}')


def train_seed(config: dict[str, Any], seed: int) -> dict[str, Any]:
    """Train one seed; return its record and actors (plain data: Ray ships it back).

    ``config`` holds train_policy's options (not --seed/--seeds/--out). The result has the
    curve, the final, before-RL and best actors (layers and meta), their held-out scores.
    """
    from stable_baselines3 import DDPG, TD3, HerReplayBuffer
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.logger import Logger
    from stable_baselines3.common.noise import NormalActionNoise
    import torch

    import ur_rg2_learning  # noqa: F401 - registers the environments (in a Ray worker too)

    started = time.monotonic()
    env_id = config['env']
    timesteps = config['timesteps']
    every = config['eval_every'] or max(timesteps // 20, 1)
    deadline = started + 60.0 * config['minutes'] if config['minutes'] else float('inf')
    torch.manual_seed(seed)
    # The networks are small: one thread computes them fastest. With one per core, torch's
    # threads wait on each other whenever the machine is busy (the environment, other
    # processes): a 256x256 layer took 18 ms instead of 1.6 ms on the loaded 2-core machine.
    torch.set_num_threads(1)
    make_kwargs = ({'grasped_share': config['grasped_share'],
                    'over_ball_share': config.get('over_ball_share', 0.0)}
                   if env_id == PICK_ID else {})
    noise = config.get('obs_noise', 0.0) / 1000  # m
    env = make(env_id, noise, **make_kwargs)
    extra: dict[str, Any] = {}
    if config.get('dataset'):
        demonstrations, extra = dataset_demonstrations(
            config['dataset'], env, config['camera_position'], config['camera_look_at'])
    else:
        demonstrations = scripted_demonstrations(env_id, config['demos'])
    mean, std = input_scaling(env_id, demonstrations)
    size = env.action_space.shape[0]
    h = HYPERPARAMETERS
    h = dict(h, net_arch=config['net'], actor_lr_share=config['actor_lr_share'])
    # Pick's rewards are -1 or 0 each step: its returns lie in [-1 / (1 - gamma), 0].
    q_bounds = (-1.0 / (1.0 - h['gamma']), 0.0) if config.get('clip_return') else None
    algorithm = with_cloning({'ddpg': DDPG, 'td3': TD3}[config['algo']], h['actor_lr_share'],
                             q_bounds, config.get('action_l2', 0.0))
    model = algorithm(
        'MultiInputPolicy', env, seed=seed, learning_rate=h['learning_rate'],
        buffer_size=min(h['buffer_size'], timesteps + len(demonstrations.get('action', []))),
        batch_size=h['batch_size'], gamma=h['gamma'], tau=h['tau'],
        # HER samples whole episodes: the first must have ended before the first update.
        learning_starts=min(h['learning_starts'], max(timesteps // 2, EPISODE_STEPS[env_id])),
        action_noise=NormalActionNoise(np.zeros(size), h['action_noise'] * np.ones(size)),
        replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs={'n_sampled_goal': h['her_goals'],
                              'goal_selection_strategy': 'future'},
        policy_kwargs={'net_arch': h['net_arch'],
                       'features_extractor_class': standardising_extractor(),
                       'features_extractor_kwargs': {'mean': mean, 'std': std}},
        verbose=0)
    # Without a logger of its own, each learn() makes an empty /tmp/SB3-<time> folder.
    model.set_logger(Logger(None, []))
    record = dict(config, seed=seed, observation_keys=list(env.observation_space.spaces),
                  action_low=env.action_space.low.tolist(),
                  action_high=env.action_space.high.tolist(), extra_meta=extra)
    add_demonstrations(model.replay_buffer, demonstrations)
    if config.get('dataset') and config['bc_epochs']:
        loss, took = clone_actor(model, demonstrations, config['bc_epochs'], seed)
        extra['cloned_before_rl'] = len(demonstrations['action'])
        extra['cloning_loss'] = round(loss, 5)
        print(f"cloned {len(demonstrations['action'])} steps of "
              f"{extra['dataset']['episodes_used']} episodes, {config['bc_epochs']} epochs: "
              f'loss {loss:.4f} in {took:.0f} s', flush=True)
    if config['bc']:
        model.cloning = Cloning(model, demonstrations, config['bc'], config['q_filter'],
                                alone=config['cloning_only'], fade=config.get('bc_fade', 0))
    warm_up_critic(model, config['critic_warmup'], q_bounds)
    curve: list[tuple[int, float, float]] = []  # (steps, success rate, wall seconds)
    before_rl = export(model, record, 0, time.monotonic() - started, curve)
    best: dict[str, Any] = {}

    def evaluate(steps: int) -> None:
        actor = export(model, record, steps, time.monotonic() - started, curve)
        rate = success_rate(actor, config['eval_episodes'], CURVE_SEED, env_id, noise)
        if not curve or rate >= max(point[1] for point in curve):
            # The best point's actor is kept too (the latest of equals: it has learned the
            # longest); the run's result is the final actor, not this one.
            best.update(actor=actor, steps=steps, success=rate)
        curve.append((steps, rate, time.monotonic() - started))
        cloned = (f'  cloned {model.cloning.share:4.2f}' if config['bc'] and config['q_filter']
                  else '')
        print(f'{env_id} {config["algo"]} seed {seed}: {steps:>8d}/{timesteps} steps  '
              f'success {rate:4.2f}  {time.monotonic() - started:6.0f} s{cloned}', flush=True)

    class Steps(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps % every == 0:
                evaluate(self.num_timesteps)
            return time.monotonic() < deadline

    evaluate(0)  # the actor before any reinforcement learning
    if timesteps:
        model.learn(timesteps, callback=Steps())
    steps = model.num_timesteps
    if curve[-1][0] != steps:
        evaluate(steps)
    seconds = time.monotonic() - started
    final = export(model, record, steps, seconds, curve)
    env.close()
    episodes = config['final_episodes']
    scores = {name: (success_rate(actor, episodes, DEFAULT_SEED, ball_noise=noise)
                     if episodes else float('nan'))
              for name, actor in (('final', final), ('before_rl', before_rl))
              if name == 'final' or steps}
    scores.setdefault('before_rl', scores['final'])  # no RL step: the same actor
    for actor in (final, before_rl, best['actor']):
        actor.meta['held_out'] = {'episodes': episodes, 'seed': DEFAULT_SEED,
                                  'obs_noise_mm': config.get('obs_noise', 0.0),
                                  'final_success': scores['final'],
                                  'before_rl_success': scores['before_rl']}
    best['actor'].meta['best_of_curve'] = {'steps': best['steps'], 'success': best['success']}
    return {
        'env': env_id, 'seed': seed, 'method': method(config), 'steps': steps,
        'seconds': seconds, 'curve': curve, 'final_episodes': episodes,
        'final': scores['final'], 'before_rl': scores['before_rl'],
        'best_success': best['success'], 'best_steps': best['steps'],
        'actors': {'final': to_data(final), 'before_rl': to_data(before_rl),
                   'best': to_data(best['actor'])},
    }


def to_data(actor: Actor) -> dict[str, Any]:
    """Return an actor as plain data (layers, meta)."""
    return {'layers': actor.layers, 'meta': actor.meta}


def write_result(result: dict[str, Any], out: Path) -> None:
    """Write a seed's actors (final into ``out``, before_rl/, best/) and its curve picture."""
    out.mkdir(parents=True, exist_ok=True)
    actors = result['actors']
    Actor(**actors['final']).save(out)
    Actor(**actors['before_rl']).save(out / 'before_rl')
    Actor(**actors['best']).save(out / 'best')
    plot_curves({result['seed']: result['curve']}, f"{result['env']}, {result['method']}",
                out / 'learning_curve.png')


def method(config: dict[str, Any]) -> str:
    """Return what trains the policy, in words."""
    if config.get('dataset'):
        name = Path(config['dataset']).name
        words = (f"behaviour cloning ({config['bc_epochs']} epochs) of the data set {name}'s "
                 'episodes')
        if not config['timesteps']:
            return words
        words = ((words + ', then ') if config['bc_epochs'] else '') + (
            f"{ALGORITHMS[config['algo']]} + HER with the data set {name}'s steps in the buffer")
    else:
        words = f"{ALGORITHMS[config['algo']]} + HER"
    if config['demos']:
        words += f" + {config['demos']} scripted demos in the buffer"
    if config['bc']:
        words += f" + {'Q-filtered ' if config['q_filter'] else ''}BC {config['bc']:g}"
        if config.get('bc_fade'):
            words += f" fading to 0 over {config['bc_fade']} steps"
        if config.get('cloning_only'):
            words += ' alone (no -Q term in the actor updates: an ablation)'
    if config['critic_warmup']:
        words += f", critic warm-up {config['critic_warmup']}"
    if config.get('grasped_share'):
        words += f", {config['grasped_share']:g} of episodes start grasped"
    if config.get('over_ball_share'):
        words += f", {config['over_ball_share']:g} start over the ball"
    if config.get('clip_return'):
        words += ', returns clipped'
    if config.get('action_l2'):
        words += f", action L2 {config['action_l2']:g}"
    if config.get('obs_noise'):
        words += f", ball observed with {config['obs_noise']:g} mm noise"
    return words


def scripted_demonstrations(env_id: str, episodes: int) -> dict[str, np.ndarray]:
    """Return ``episodes`` of the scripted pick, one row a step: each key, and the rest.

    Keys: the observation's, ``action``, ``next_<key>``, ``reward``, ``done``, ``truncated``.
    Each episode ends DEMO_HOLD_STEPS steps after the ball is first lifted (cut there, as by
    a time limit): the whole 100 steps would be mostly the ball held still.
    """
    from ur_rg2_learning.scripted import pick_action

    if not episodes:
        return {}
    env = gym.make(env_id)
    rows: dict[str, list[Any]] = {}
    try:
        for episode in range(episodes):
            observation, _ = env.reset(seed=DEMO_SEED + episode)
            done, held = False, 0
            while not done:
                action = pick_action(observation)
                following, reward, terminated, truncated, info = env.step(action)
                held += bool(info['is_success'])
                truncated = truncated or held > DEMO_HOLD_STEPS
                done = terminated or truncated
                row = {**observation, 'action': action, 'reward': reward, 'done': done,
                       'truncated': truncated and not terminated,
                       **{f'next_{key}': value for key, value in following.items()}}
                for key, value in row.items():
                    rows.setdefault(key, []).append(value)
                observation = following
    finally:
        env.close()
    return {key: np.array(values) for key, values in rows.items()}


def clone_actor(model, demonstrations: dict[str, np.ndarray], epochs: int,
                seed: int) -> tuple[float, float]:
    """Fit the model's actor to the demonstrated actions (mean squared error, Adam).

    ``epochs`` passes in batches of the model's batch size; the actor's target is set to the
    result. Return the last epoch's mean loss and the seconds taken.
    """
    import torch

    started = time.monotonic()
    device = model.device
    observations = {key: torch.as_tensor(demonstrations[key], device=device)
                    for key in model.observation_space.spaces}
    # Short of tanh's saturation: a network fitted to +-1 exactly (the gripper's commands, the
    # fastest moves) gets no gradient there when reinforcement learning takes over.
    actions = torch.as_tensor(demonstrations['action'], device=device).clamp(
        -CLONING_BOUND, CLONING_BOUND)
    optimizer = torch.optim.Adam(model.actor.parameters(), lr=CLONING_LR)
    rng = np.random.default_rng(seed)
    model.policy.set_training_mode(True)
    loss_sum = 0.0
    for _ in range(epochs):
        order = torch.as_tensor(rng.permutation(len(actions)), device=device)
        loss_sum, batches = 0.0, 0
        for rows in order.split(model.batch_size):
            predicted = model.actor({key: value[rows] for key, value in observations.items()})
            loss = ((predicted - actions[rows]) ** 2).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            loss_sum, batches = loss_sum + loss.item(), batches + 1
        loss_sum /= batches
    model.policy.set_training_mode(False)
    model.actor_target.load_state_dict(model.actor.state_dict())
    return loss_sum, time.monotonic() - started


def add_demonstrations(buffer, demonstrations: dict[str, np.ndarray]) -> None:
    """Put the demonstrated steps into the (HER) replay buffer, as if the agent had acted."""
    keys = ('achieved_goal', 'desired_goal', 'observation')
    for i in range(len(demonstrations.get('action', []))):
        d = demonstrations
        buffer.add({key: d[key][i][None] for key in keys},
                   {key: d[f'next_{key}'][i][None] for key in keys},
                   d['action'][i][None], np.array([d['reward'][i]]), np.array([d['done'][i]]),
                   # Stable-Baselines3's flag for an episode cut by its time limit.
                   [{'TimeLimit.truncated': bool(d['truncated'][i])}])


def input_scaling(env_id: str, demonstrations: dict[str, np.ndarray]) -> tuple[list, list]:
    """Return the inputs' mean and deviation, in the actor's input order (sorted keys).

    From the demonstrations, else from NORMALISE_EPISODES random episodes; fixed for the run
    (the export folds them into the first layer). Deviations below INPUT_STD_FLOOR are taken
    as it: with 1 cm, inputs the demonstrations hardly vary (the goal's height, the ball's
    speed) came out at 100 and more wherever the policy strayed from them, and a policy that
    matched the demonstrated actions within 0.02 lifted no ball; with 5 cm, 9 of 10.
    """
    if not demonstrations:
        env = gym.make(env_id)
        rng = np.random.default_rng(0)
        rows: dict[str, list] = {}
        try:
            for episode in range(NORMALISE_EPISODES):
                observation, _ = env.reset(seed=DEMO_SEED + episode)
                done = False
                while not done:
                    for key, value in observation.items():
                        rows.setdefault(key, []).append(value)
                    action = rng.uniform(-1, 1, env.action_space.shape)
                    observation, _, terminated, truncated, _ = env.step(action)
                    done = terminated or truncated
        finally:
            env.close()
        demonstrations = {key: np.array(values) for key, values in rows.items()}
    keys = sorted(('achieved_goal', 'desired_goal', 'observation'))
    values = np.concatenate([demonstrations[key] for key in keys], axis=1)
    return values.mean(axis=0).tolist(), np.maximum(values.std(axis=0), INPUT_STD_FLOOR).tolist()


def standardising_extractor() -> type:
    """Return Stable-Baselines3's dict extractor with its output standardised (fixed)."""
    from stable_baselines3.common.torch_layers import CombinedExtractor
    import torch

    class StandardisingExtractor(CombinedExtractor):
        def __init__(self, observation_space, mean: list, std: list) -> None:
            super().__init__(observation_space)
            self.register_buffer('mean', torch.tensor(mean, dtype=torch.float32))
            self.register_buffer('std', torch.tensor(std, dtype=torch.float32))

        def forward(self, observations):
            return (super().forward(observations) - self.mean) / self.std

    return StandardisingExtractor


def with_cloning(algorithm: type, actor_lr_share: float,
                 q_bounds: tuple[float, float] | None = None, action_l2: float = 0.0) -> type:
    """Return a subclass of a Stable-Baselines3 TD3-family class with its own update.

    The update is the algorithm's (clipped double Q where there are twin critics, target
    policy smoothing as configured, delayed actor updates) plus: the critic's targets clipped
    to ``q_bounds`` (the returns the rewards allow, as the HER baselines clip them), an
    ``action_l2`` penalty on the actor's moves, ``model.cloning``'s term in the actor loss,
    and the actor's learning rate ``actor_lr_share`` of the critic's.
    """
    from stable_baselines3.common.utils import polyak_update

    class WithCloning(algorithm):
        cloning: Cloning | None = None

        def _update_learning_rate(self, optimizers) -> None:
            super()._update_learning_rate(optimizers)
            for group in self.actor.optimizer.param_groups:
                group['lr'] = self.lr_schedule(self._current_progress_remaining) * actor_lr_share

        def train(self, gradient_steps: int, batch_size: int = 100) -> None:
            self.policy.set_training_mode(True)
            self._update_learning_rate([self.actor.optimizer, self.critic.optimizer])
            for _ in range(gradient_steps):
                self._n_updates += 1
                data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
                update_critic(self, data, q_bounds)
                if self._n_updates % self.policy_delay == 0:
                    self.update_actor(data, batch_size)
                    polyak_update(self.critic.parameters(), self.critic_target.parameters(),
                                  self.tau)
                    polyak_update(self.actor.parameters(), self.actor_target.parameters(),
                                  self.tau)

        def update_actor(self, data, batch_size: int) -> None:
            actions = self.actor(data.observations)
            loss = actions.new_zeros(())
            if self.cloning is None or not self.cloning.alone:
                loss = loss - self.critic.q1_forward(data.observations, actions).mean()
            if action_l2:
                loss = loss + action_l2 * (actions[:, :3] ** 2).mean()
            if self.cloning is not None:
                loss = loss + self.cloning.loss(batch_size)
            self.actor.optimizer.zero_grad()
            loss.backward()
            self.actor.optimizer.step()

        def _excluded_save_params(self) -> list[str]:
            return [*super()._excluded_save_params(), 'cloning']

    WithCloning.__name__ = algorithm.__name__
    return WithCloning


def update_critic(model, data, q_bounds: tuple[float, float] | None = None) -> None:
    """One TD3-family critic update on a replay batch, targets clipped to ``q_bounds``."""
    import torch
    from torch.nn import functional

    with torch.no_grad():
        noise = (data.actions.clone().normal_(0, model.target_policy_noise)
                 .clamp(-model.target_noise_clip, model.target_noise_clip))
        following = (model.actor_target(data.next_observations) + noise).clamp(-1, 1)
        next_q = torch.cat(model.critic_target(data.next_observations, following), dim=1)
        next_q, _ = torch.min(next_q, dim=1, keepdim=True)
        discounts = data.discounts if data.discounts is not None else model.gamma
        target = data.rewards + (1 - data.dones) * discounts * next_q
        if q_bounds is not None:
            target = target.clamp(*q_bounds)
    current = model.critic(data.observations, data.actions)
    loss = sum(functional.mse_loss(q, target) for q in current)
    model.critic.optimizer.zero_grad()
    loss.backward()
    model.critic.optimizer.step()


def warm_up_critic(model, updates: int, q_bounds: tuple[float, float] | None = None) -> None:
    """Train the critic ``updates`` times on the replay buffer (the demonstrations) alone.

    The critic update of :func:`with_cloning`'s class, with the actor fixed and the critic's
    target following.
    """
    from stable_baselines3.common.utils import polyak_update

    for _ in range(updates):
        update_critic(model, model.replay_buffer.sample(model.batch_size,
                                                        env=model._vec_normalize_env), q_bounds)
        polyak_update(model.critic.parameters(), model.critic_target.parameters(), model.tau)


class Cloning:
    """Behaviour cloning of demonstrations into a TD3-family actor (Nair et al., 2018).

    Each update draws a batch of demonstrated steps; the loss is the squared distance from the
    actor's actions to the demonstrated ones, on the steps where the critics value the
    demonstrated action above the actor's (the Q-filter, so that the actor may outgrow a
    demonstrator the critic finds worse; the twin critics' minimum on both sides, so that an
    action the critics have not seen is not rated up by one of them), times ``weight`` and the
    batch's mean |Q| (as TD3+BC, Fujimoto and Gu 2021, balances it against the actor loss -Q,
    whatever the scale of the returns).
    """

    def __init__(self, model, demonstrations: dict[str, np.ndarray], weight: float,
                 q_filter: bool = True, alone: bool = False, fade: int = 0) -> None:
        import torch

        self._torch = torch
        self.model = model
        self.weight = weight
        self.q_filter = q_filter
        self.alone = alone  # the actor loss is this term alone (an ablation)
        self.fade = fade  # environment steps over which the weight falls to 0 (0: never)
        self.share = 1.0  # the share of demonstrated steps the last filter let through
        device = model.device
        self.actions = torch.as_tensor(demonstrations['action'], device=device)
        self.observations = {key: torch.as_tensor(demonstrations[key], device=device)
                             for key in model.observation_space.spaces}
        self._rng = np.random.default_rng(model.seed)

    def loss(self, batch_size: int):
        """Return the cloning loss on a batch of demonstrated steps (a torch scalar)."""
        torch = self._torch
        model = self.model
        rows = torch.as_tensor(self._rng.integers(0, len(self.actions), batch_size))
        observations = {key: value[rows] for key, value in self.observations.items()}
        demonstrated = self.actions[rows]
        actions = model.actor(observations)
        error = ((actions - demonstrated) ** 2).sum(dim=1)
        with torch.no_grad():
            q_demonstrated = torch.cat(model.critic(observations, demonstrated), dim=1).amin(1)
            q_actor = torch.cat(model.critic(observations, actions), dim=1).amin(1)
            better = (q_demonstrated > q_actor).float()
            fading = max(0.0, 1.0 - model.num_timesteps / self.fade) if self.fade else 1.0
            scale = self.weight * fading * q_actor.abs().mean()
        if self.q_filter:
            self.share = better.mean().item()
            error = error * better
        return scale * error.mean()


def export(model, record: dict[str, Any], steps: int, seconds: float,
           curve: list[tuple[int, float, float]]) -> Actor:
    """Return the model's actor as a NumPy :class:`Actor` with its training record."""
    # Stable-Baselines3's MultiInputPolicy flattens the observation dict in the space's order;
    # the fixed standardisation folds into the first layer.
    network = model.actor.mu
    linear = [layer for layer in network if hasattr(layer, 'weight')]
    layers = [(layer.weight.detach().cpu().numpy().astype(np.float64),
               layer.bias.detach().cpu().numpy().astype(np.float64)) for layer in linear]
    extractor = model.actor.features_extractor
    mean = extractor.mean.cpu().numpy().astype(np.float64)
    std = extractor.std.cpu().numpy().astype(np.float64)
    weight, bias = layers[0]
    layers[0] = (weight / std, bias - (weight / std) @ mean)
    meta = {
        'env_id': record['env'],
        'algo': record['algo'],
        'method': method(record),
        'command': record.get('command'),
        'observation_keys': record['observation_keys'],
        'action_low': record['action_low'],
        'action_high': record['action_high'],
        'episode_steps': EPISODE_STEPS[record['env']],
        'timesteps': steps,
        'seed': record['seed'],
        'demos': record['demos'],
        'cloned_before_rl': 0,  # demonstrations cloned before the first update: none
        **record.get('extra_meta', {}),
        'bc': record['bc'],
        'bc_fade': record.get('bc_fade', 0),
        'q_filter': record['q_filter'],
        'cloning_only': record.get('cloning_only', False),
        'critic_warmup': record['critic_warmup'],
        'grasped_share': record['grasped_share'],
        'over_ball_share': record.get('over_ball_share', 0.0),
        'clip_return': record.get('clip_return', False),
        'action_l2': record.get('action_l2', 0.0),
        'obs_noise_mm': record.get('obs_noise', 0.0),
        'train_seconds': round(seconds, 1),
        'hyperparameters': dict(HYPERPARAMETERS, net_arch=record['net'],
                                actor_lr_share=record['actor_lr_share'],
                                learning_starts=model.learning_starts),
        'rl_updates': int(model._n_updates),
        'curve': [{'steps': s, 'success': r, 'seconds': round(t, 1)} for s, r, t in curve],
    }
    return Actor(layers, meta)


def plot_curves(curves: dict[int, list[tuple[int, float, float]]], title: str,
                path: Path) -> None:
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


if __name__ == '__main__':
    sys.exit(main())
