"""The demonstrations a policy learns from, and the cloning of them into its actor.

:func:`scripted_demonstrations` runs the scripted pick (:mod:`ur_rg2_learning.scripted`) for a
number of episodes; :mod:`ur_rg2_learning.dataset_demos` gives a LeRobot data set's steps in
the same form. :func:`add_demonstrations` puts them into the (HER) replay buffer,
:func:`input_scaling` takes the inputs' mean and deviation from them, :func:`clone_actor`
fits an actor to them before reinforcement learning (``--dataset``), and :class:`Cloning` is
the Q-filtered cloning term of the actor updates (``--bc``).
"""

from __future__ import annotations

import time
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from ur_rg2_learning.scripted import pick_action

DEMO_SEED = 700_000  # the demonstrations' episodes, apart from training's and evaluation's
DEMO_HOLD_STEPS = 10  # steps of each demonstration after the ball is lifted
INPUT_STD_FLOOR = 0.05  # m, m/s: the least deviation an input is standardised with
NORMALISE_EPISODES = 10  # random episodes that set the input scaling when there are no demos
CLONING_LR = 1e-3  # --dataset: Adam's learning rate for the cloning
CLONING_BOUND = 0.9  # --dataset: the cloned actions are clipped to this, short of +-1


def scripted_demonstrations(env_id: str, episodes: int) -> dict[str, np.ndarray]:
    """Return ``episodes`` of the scripted pick, one row a step: each key, and the rest.

    Keys: the observation's, ``action``, ``next_<key>``, ``reward``, ``done``, ``truncated``.
    Each episode ends DEMO_HOLD_STEPS steps after the ball is first lifted (cut there, as by
    a time limit): the whole 100 steps would be mostly the ball held still.
    """
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


def clone_actor(model: Any, demonstrations: dict[str, np.ndarray], epochs: int,
                seed: int) -> tuple[float, float]:
    """Fit the model's actor to the demonstrated actions (mean squared error, Adam).

    ``epochs`` passes in batches of the model's batch size; the actor's target is set to the
    result. Return the last epoch's mean loss and the seconds taken.
    """
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


def add_demonstrations(buffer: Any, demonstrations: dict[str, np.ndarray]) -> None:
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


class Cloning:
    """Behaviour cloning of demonstrations into a TD3-family actor (Nair et al., 2018).

    Each update draws a batch of demonstrated steps; the loss is the squared distance from the
    actor's actions to the demonstrated ones, on the steps where the critics value the
    demonstrated action above the actor's (the Q-filter, so that the actor may outgrow a
    demonstrator the critic finds worse; the twin critics' minimum on both sides, so that an
    action the critics have not seen is not rated up by one of them), times ``weight`` and the
    batch's mean |Q| (as TD3+BC, Fujimoto and Gu 2021, balances it against the actor loss -Q,
    whatever the scale of the returns).

    :param model: the TD3-family model whose actor learns (its critics rate the actions)
    :param demonstrations: the demonstrated steps (the observation's keys and ``action``)
    :param weight: the term's weight, times the batch's mean |Q|
    :param q_filter: clone only the steps the critics rate above the actor's action
    :param alone: the actor loss is this term alone, without -Q (an ablation)
    :param fade: environment steps over which the weight falls to 0 (0: it stays)
    """

    def __init__(self, model: Any, demonstrations: dict[str, np.ndarray], weight: float,
                 q_filter: bool = True, alone: bool = False, fade: int = 0) -> None:
        self.model = model
        self.weight = weight
        self.q_filter = q_filter
        self.alone = alone
        self.fade = fade
        self.share = 1.0  # the share of demonstrated steps the last filter let through
        device = model.device
        self.actions = torch.as_tensor(demonstrations['action'], device=device)
        self.observations = {key: torch.as_tensor(demonstrations[key], device=device)
                             for key in model.observation_space.spaces}
        self._rng = np.random.default_rng(model.seed)

    def loss(self, batch_size: int) -> torch.Tensor:
        """Return the cloning loss on a batch of demonstrated steps (a torch scalar)."""
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
