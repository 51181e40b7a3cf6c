"""``evaluate_policy``: the success rate of a trained policy over held-out episodes.

Runs the exported actor (NumPy, no torch) on fresh environments seeded ``--seed``,
``--seed + 1``, ...; an episode succeeds when ``info['is_success']`` holds at its last step
(the TCP has to stay at the ball, not pass by it), as Gymnasium-Robotics counts it.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
import sys
from typing import Any

import gymnasium as gym

import ur_rg2_learning  # noqa: F401 - registers the environments
from ur_rg2_learning.actor import SHIPPED, Actor, PolicyError, shipped_policy

# Training seeds its environment with small numbers: these episodes are held out.
DEFAULT_SEED = 1_000_000


def success_rate(actor: Actor | Callable[[Any], Any], episodes: int, seed: int,
                 env_id: str | None = None) -> float:
    """Return the share of ``episodes`` the actor finishes successfully.

    ``actor`` is an :class:`Actor` or any function from observation to action, with
    ``env_id`` then naming the environment.
    """
    env = gym.make(env_id or actor.env_id)
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
    parser.add_argument('--seed', type=int, default=DEFAULT_SEED,
                        help=f'seed of the first episode ({DEFAULT_SEED}, held out)')
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error('--episodes must be at least 1')
    try:
        actor = Actor.load(shipped_policy(args.policy) if args.policy in SHIPPED
                           else args.policy)
    except PolicyError as error:
        print(f'evaluate_policy: {error}', file=sys.stderr)
        return 2
    rate = success_rate(actor, args.episodes, args.seed)
    print(f'success rate {rate:.2f} over {args.episodes} episodes')
    return 0


if __name__ == '__main__':
    sys.exit(main())
