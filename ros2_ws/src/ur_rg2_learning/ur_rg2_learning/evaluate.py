"""``evaluate_policy``: the success rate of a trained policy over held-out episodes.

Runs the exported actor (NumPy, no torch) on fresh environments seeded ``--seed``,
``--seed + 1``, ...; an episode succeeds when ``info['is_success']`` holds at its last step
(the TCP has to stay at the ball, not pass by it), as Gymnasium-Robotics counts it.

Two ranges of episodes are held out from training: ``--seed``'s default, 1000000 on, which
training's own held-out scores use and recipes have been compared on, and the final test
range (``--final``: 100 episodes from 2000000), which no recipe choice looks at and which is
reported once per shipped policy. ``--obs-noise MM`` observes Pick's ball with Gaussian noise
of MM mm per axis (:class:`ur_rg2_learning.envs.BallNoise`; ``vision`` for the vision node's
error, VISION_BALL_NOISE).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
import sys
from typing import Any

import ur_rg2_learning  # noqa: F401 - registers the environments
from ur_rg2_learning.actor import SHIPPED, Actor, PolicyError, shipped_policy
from ur_rg2_learning.envs import VISION_BALL_NOISE, make

# Training seeds its environment with small numbers: these episodes are held out.
DEFAULT_SEED = 1_000_000
# The final test range: held out from training and from every choice between recipes (which
# DEFAULT_SEED's episodes have served); run once per shipped policy (evaluate_policy --final).
FINAL_TEST_SEED = 2_000_000
FINAL_TEST_EPISODES = 100


def success_rate(actor: Actor | Callable[[Any], Any], episodes: int, seed: int,
                 env_id: str | None = None, ball_noise: float = 0.0) -> float:
    """Return the share of ``episodes`` the actor finishes successfully.

    ``actor`` is an :class:`Actor` or any function from observation to action, with
    ``env_id`` then naming the environment; ``ball_noise`` (m per axis, Pick only) observes
    the ball with that noise.
    """
    env = make(env_id or actor.env_id, ball_noise)
    successes = 0
    try:
        for episode in range(episodes):
            observation, info = env.reset(seed=seed + episode)
            done = False
            while not done:
                observation, _, terminated, truncated, info = env.step(actor(observation))
                done = terminated or truncated
            successes += bool(info['is_success'])
    finally:
        env.close()
    return successes / episodes


def main(argv: list[str] | None = None) -> int:
    """Print ``success rate R over N episodes``; exit code 0, 2 on a bad policy directory."""
    parser = argparse.ArgumentParser(prog='evaluate_policy', description=__doc__.split('\n')[0])
    parser.add_argument('--policy', required=True,
                        help='policy directory (train_policy --out), or a policy shipped with '
                        "the package: 'reach' or 'pick', as the policy node's policy_dir")
    parser.add_argument('--episodes', type=int, default=100, help='episodes to run (100)')
    seeds = parser.add_mutually_exclusive_group()
    seeds.add_argument('--seed', type=int, default=DEFAULT_SEED,
                       help=f'seed of the first episode ({DEFAULT_SEED}, held out)')
    seeds.add_argument('--final', action='store_true',
                       help=f'the final test range: {FINAL_TEST_EPISODES} episodes from '
                       f'{FINAL_TEST_SEED}, which no recipe choice has looked at')
    parser.add_argument('--obs-noise', type=noise_mm, default=0.0, metavar='MM',
                        help="Pick: Gaussian noise on the observed ball, mm per axis, or 'vision' "
                        f'({VISION_BALL_NOISE * 1000:g} mm, as vision errs); 0: none')
    args = parser.parse_args(argv)
    if args.final:
        args.seed = FINAL_TEST_SEED
        if args.episodes != FINAL_TEST_EPISODES:
            parser.error(f'--final is {FINAL_TEST_EPISODES} episodes')
    if args.episodes < 1:
        parser.error('--episodes must be at least 1')
    try:
        actor = Actor.load(shipped_policy(args.policy) if args.policy in SHIPPED
                           else args.policy)
    except PolicyError as error:
        print(f'evaluate_policy: {error}', file=sys.stderr)
        return 2
    try:
        rate = success_rate(actor, args.episodes, args.seed, ball_noise=args.obs_noise / 1000)
    except ValueError as error:  # noise on a Reach policy
        print(f'evaluate_policy: {error}', file=sys.stderr)
        return 2
    where = [f'final test range {FINAL_TEST_SEED}-{FINAL_TEST_SEED + args.episodes - 1}'
             ] if args.final else []
    if args.obs_noise:
        where.append(f'ball noise {args.obs_noise:g} mm per axis')
    print(f'success rate {rate:.2f} over {args.episodes} episodes'
          + (f" ({', '.join(where)})" if where else ''))
    return 0


def noise_mm(text: str) -> float:
    """Return a noise option's mm: a number (not negative) or ``vision``."""
    if text == 'vision':
        return VISION_BALL_NOISE * 1000
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number of mm or 'vision': {text}") from None
    if not value >= 0:
        raise argparse.ArgumentTypeError(f'must not be negative: {text}')
    return value


if __name__ == '__main__':
    sys.exit(main())
