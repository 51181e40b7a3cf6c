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

from ur_rg2_learning import PICK_ID, REACH_ID
from ur_rg2_learning.dataset_demos import DatasetError, read_dataset
from ur_rg2_learning.evaluate import noise_mm
from ur_rg2_learning.train_config import ALGORITHMS, TrainConfig


def parser() -> argparse.ArgumentParser:
    """Return train_policy's argument parser."""
    p = argparse.ArgumentParser(prog='train_policy', description=__doc__.split('\n')[0])
    p.add_argument('--env', choices=[REACH_ID, PICK_ID],
                   help=f'the environment (required; {PICK_ID} with --dataset)')
    p.add_argument('--algo', default=TrainConfig.algo, choices=list(ALGORITHMS))
    p.add_argument('--timesteps', type=int,
                   help='environment steps (at most; required unless --dataset)')
    p.add_argument('--dataset', metavar='DIR',
                   help=f"{PICK_ID} from a LeRobot data set (to_lerobot's): behaviour cloning "
                   'of its steps, then --finetune-steps of TD3 + HER with them in the buffer')
    p.add_argument('--bc-epochs', type=int, default=TrainConfig.bc_epochs,
                   help='with --dataset: epochs of behaviour cloning (%(default)s)')
    p.add_argument('--finetune-steps', type=int, default=0,
                   help='with --dataset: environment steps of TD3 + HER after the cloning (0)')
    p.add_argument('--camera-position', type=float, nargs=3, metavar=('X', 'Y', 'Z'),
                   default=TrainConfig.camera_position,
                   help="with --dataset: the recording's camera_position (world, m; the sim's "
                   'default %(default)s)')
    p.add_argument('--camera-look-at', type=float, nargs=3, metavar=('X', 'Y', 'Z'),
                   default=TrainConfig.camera_look_at,
                   help="with --dataset: the recording's camera_look_at (%(default)s)")
    seeds = p.add_mutually_exclusive_group()
    seeds.add_argument('--seed', type=int, default=0, help='one seed, in this process (0)')
    seeds.add_argument('--seeds', type=int, nargs='+',
                       help='several seeds, each a Ray task (writes seed_N/ for each)')
    p.add_argument('--out', required=True, help='directory to write the policy to')
    p.add_argument('--minutes', type=float, default=TrainConfig.minutes,
                   help='wall time per seed at most (0: no bound); the run ends there')
    p.add_argument('--eval-every', type=int, default=TrainConfig.eval_every,
                   help='steps between learning-curve points (default: timesteps / 20)')
    p.add_argument('--eval-episodes', type=int, default=TrainConfig.eval_episodes,
                   help='episodes per learning-curve point (%(default)s)')
    p.add_argument('--final-episodes', type=int, default=TrainConfig.final_episodes,
                   help='held-out episodes scoring the final and the before-RL actor '
                   '(%(default)s)')
    p.add_argument('--demos', type=int, default=TrainConfig.demos,
                   help=f'{PICK_ID} only: scripted pick episodes put into the replay buffer')
    p.add_argument('--bc', type=float, default=TrainConfig.bc,
                   help='weight of the behaviour-cloning term in the actor updates (0: none; '
                   'needs --demos)')
    p.add_argument('--bc-fade', type=int, default=TrainConfig.bc_fade,
                   help='environment steps over which the cloning weight falls linearly to 0 '
                   '(0: it stays); after them the actor learns from the critic alone')
    p.add_argument('--no-q-filter', dest='q_filter', action='store_false',
                   help='clone every demonstrated step, not only those the critic rates above '
                   'the actor')
    p.add_argument('--cloning-only', action='store_true',
                   help="ablation: the algorithm's -Q term taken out of the actor updates, "
                   'nothing else (the Q-filter, unless --no-q-filter, and --action-l2 stay; '
                   'the critic still learns; needs --bc)')
    p.add_argument('--critic-warmup', type=int, default=TrainConfig.critic_warmup,
                   help='critic updates on the demonstrations before the first step (0)')
    p.add_argument('--grasped-share', type=float, default=TrainConfig.grasped_share,
                   help=f'{PICK_ID} only: share of training episodes that start with the ball '
                   'between the fingers (0)')
    p.add_argument('--over-ball-share', type=float, default=TrainConfig.over_ball_share,
                   help=f'{PICK_ID} only: share of training episodes that start with the open '
                   'fingers round or over the ball (0)')
    p.add_argument('--clip-return', action='store_true',
                   help=f"{PICK_ID} only: clip the critic's targets to the returns its rewards "
                   '(-1 or 0) allow, as the HER baselines do')
    p.add_argument('--action-l2', type=float, default=TrainConfig.action_l2,
                   help="weight of a penalty on the actor's squared moves (0; the HER "
                   'baselines use 1)')
    p.add_argument('--obs-noise', type=noise_mm, default=TrainConfig.obs_noise_mm, metavar='MM',
                   help=f"{PICK_ID} only: Gaussian noise on the observed ball, mm per axis, or "
                   "'vision' (training and its evaluations; 0: none)")
    p.add_argument('--net', type=int, nargs='+', default=TrainConfig.net_arch,
                   help='hidden layer sizes of actor and critic (%(default)s)')
    p.add_argument('--actor-lr-share', type=float, default=TrainConfig.actor_lr_share,
                   help="the actor's learning rate as a share of the critic's (%(default)s)")
    p.add_argument('--num-cpus', type=int, default=None,
                   help='with --seeds: CPUs of the local Ray (default: all)')
    p.add_argument('--address', default=None,
                   help='with --seeds: an existing Ray cluster (auto or HOST:PORT)')
    return p


def check(p: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Refuse options that do not go together (exit 2); a data set trains Pick."""
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


def config_of(args: argparse.Namespace, command: list[str]) -> TrainConfig:
    """Return the checked options as a TrainConfig; ``command`` is the command line's words."""
    return TrainConfig(
        env_id=args.env, algo=args.algo, command=shlex.join(['train_policy', *command]),
        demos=args.demos, bc=args.bc, bc_fade=args.bc_fade, q_filter=args.q_filter,
        cloning_only=args.cloning_only, critic_warmup=args.critic_warmup,
        grasped_share=args.grasped_share, over_ball_share=args.over_ball_share,
        clip_return=args.clip_return, action_l2=args.action_l2, obs_noise_mm=args.obs_noise,
        net_arch=tuple(args.net), actor_lr_share=args.actor_lr_share, timesteps=args.timesteps,
        dataset=args.dataset, bc_epochs=args.bc_epochs,
        camera_position=tuple(args.camera_position), camera_look_at=tuple(args.camera_look_at),
        minutes=args.minutes, eval_every=args.eval_every, eval_episodes=args.eval_episodes,
        final_episodes=args.final_episodes)


def main(argv: list[str] | None = None) -> int:
    """Train, export, plot; exit code 0, 2 without the learning set-up, 130 on Ctrl-C."""
    p = parser()
    args = p.parse_args(argv)
    check(p, args)
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
    # The training modules import torch: only now that it is there.
    from ur_rg2_learning.seeds import run_seeds
    from ur_rg2_learning.training_run import summary, train_seed, write_result

    config = config_of(args, sys.argv[1:] if argv is None else argv)
    out = Path(args.out)
    try:
        if args.seeds is None:
            result = train_seed(config, args.seed)
            write_result(result, out)
            print(summary(result, out))
            return 0
        return run_seeds(config, args.seeds, out, args.num_cpus, args.address)
    except DatasetError as error:
        print(f'train_policy: {error}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'train_policy: interrupted; nothing written to {out}', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
