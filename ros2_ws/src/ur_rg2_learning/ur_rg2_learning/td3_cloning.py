"""TD3 and DDPG with behaviour cloning, clipped targets and an action penalty (Stable-Baselines3).

:class:`TD3Cloning` is Stable-Baselines3's TD3 whose ``train()`` is TD3's own (clipped double
Q, target policy smoothing, delayed actor updates) plus: the critic's targets clipped to
``q_bounds`` (the returns the rewards allow, as the HER baselines clip them), an ``action_l2``
penalty on the actor's moves, the ``cloning`` term
(:class:`ur_rg2_learning.demonstrations.Cloning`) in the actor loss, and the actor's learning
rate ``actor_lr_share`` of the critic's; :meth:`TD3Cloning.warm_up_critic` trains the critic
alone on the replay buffer before learning. :class:`DDPGCloning` is the same on DDPG's
settings (one critic, no target smoothing, the actor every update). ``train()`` logs as TD3's
does (``train/critic_loss``, ``train/actor_loss``), with ``train/cloning_loss`` beside them.
:class:`StandardisingExtractor` standardises the inputs with a fixed mean and deviation.
"""

from __future__ import annotations

from typing import Any

from gymnasium import spaces
import numpy as np
from stable_baselines3 import DDPG, TD3
from stable_baselines3.common.torch_layers import CombinedExtractor
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.utils import polyak_update
import torch
from torch.nn import functional

from ur_rg2_learning.demonstrations import Cloning


class StandardisingExtractor(CombinedExtractor):
    """Stable-Baselines3's dict extractor with its output standardised (fixed for the run)."""

    def __init__(self, observation_space: spaces.Dict, mean: list[float],
                 std: list[float]) -> None:
        """Flatten as CombinedExtractor does, then standardise.

        :param observation_space: the environment's dict observation space
        :param mean: the flattened inputs' mean (in the space's key order)
        :param std: their deviation
        """
        super().__init__(observation_space)
        self.register_buffer('mean', torch.tensor(mean, dtype=torch.float32))
        self.register_buffer('std', torch.tensor(std, dtype=torch.float32))

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        """Return the flattened observations, standardised."""
        return (super().forward(observations) - self.mean) / self.std


class TD3Cloning(TD3):
    """TD3 with clipped targets, an action penalty and a behaviour-cloning term.

    :param policy: the policy model to use (``'MultiInputPolicy'``, ...), as TD3's
    :param env: the environment to learn from, as TD3's
    :param actor_lr_share: the actor's learning rate as a share of the critic's
    :param q_bounds: the bounds the critic's targets are clipped to (None: not clipped)
    :param action_l2: the weight of the penalty on the actor's squared moves (0: none)
    :param kwargs: TD3's other arguments
    """

    def __init__(self, policy: str | type, env: Any, *, actor_lr_share: float = 1.0,
                 q_bounds: tuple[float, float] | None = None, action_l2: float = 0.0,
                 **kwargs: Any) -> None:
        self.actor_lr_share = actor_lr_share
        self.q_bounds = q_bounds
        self.action_l2 = action_l2
        # The cloning term of the actor updates (None: none); set once the buffer holds the
        # demonstrations.
        self.cloning: Cloning | None = None
        super().__init__(policy, env, **kwargs)

    def _update_learning_rate(self, optimizers: list[torch.optim.Optimizer]
                              | torch.optim.Optimizer) -> None:
        super()._update_learning_rate(optimizers)
        for group in self.actor.optimizer.param_groups:
            group['lr'] = self.lr_schedule(self._current_progress_remaining) * self.actor_lr_share

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        """Run ``gradient_steps`` updates on replay batches, as TD3's own update does.

        :param gradient_steps: the critic updates to run (the actor's follow every
            ``policy_delay``-th)
        :param batch_size: the replay batch of each update
        """
        self.policy.set_training_mode(True)
        self._update_learning_rate([self.actor.optimizer, self.critic.optimizer])
        actor_losses, critic_losses, cloning_losses = [], [], []
        for _ in range(gradient_steps):
            self._n_updates += 1
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
            critic_losses.append(self.update_critic(data))
            if self._n_updates % self.policy_delay == 0:
                actor_loss, cloning_loss = self.update_actor(data, batch_size)
                actor_losses.append(actor_loss)
                cloning_losses.append(cloning_loss)
                polyak_update(self.critic.parameters(), self.critic_target.parameters(),
                              self.tau)
                polyak_update(self.actor.parameters(), self.actor_target.parameters(), self.tau)
                polyak_update(self.critic_batch_norm_stats,
                              self.critic_batch_norm_stats_target, 1.0)
                polyak_update(self.actor_batch_norm_stats,
                              self.actor_batch_norm_stats_target, 1.0)
        self.logger.record('train/n_updates', self._n_updates, exclude='tensorboard')
        if actor_losses:
            self.logger.record('train/actor_loss', np.mean(actor_losses))
            if self.cloning is not None:
                self.logger.record('train/cloning_loss', np.mean(cloning_losses))
        self.logger.record('train/critic_loss', np.mean(critic_losses))

    def update_critic(self, data: ReplayBufferSamples) -> float:
        """Run one critic update on a replay batch, targets clipped to ``q_bounds``.

        :param data: the replay batch
        :return: the critic loss
        """
        with torch.no_grad():
            noise = (data.actions.clone().normal_(0, self.target_policy_noise)
                     .clamp(-self.target_noise_clip, self.target_noise_clip))
            following = (self.actor_target(data.next_observations) + noise).clamp(-1, 1)
            next_q = torch.cat(self.critic_target(data.next_observations, following), dim=1)
            next_q, _ = torch.min(next_q, dim=1, keepdim=True)
            discounts = data.discounts if data.discounts is not None else self.gamma
            target = data.rewards + (1 - data.dones) * discounts * next_q
            if self.q_bounds is not None:
                target = target.clamp(*self.q_bounds)
        current = self.critic(data.observations, data.actions)
        loss = sum(functional.mse_loss(q, target) for q in current)
        self.critic.optimizer.zero_grad()
        loss.backward()
        self.critic.optimizer.step()
        return loss.item()

    def update_actor(self, data: ReplayBufferSamples, batch_size: int) -> tuple[float, float]:
        """Run one actor update: -Q, the action penalty and the cloning term.

        :param data: the replay batch
        :param batch_size: the batch of demonstrated steps the cloning term draws
        :return: the actor loss and its cloning term (0.0 without one)
        """
        actions = self.actor(data.observations)
        loss = actions.new_zeros(())
        if self.cloning is None or not self.cloning.alone:
            loss = loss - self.critic.q1_forward(data.observations, actions).mean()
        if self.action_l2:
            loss = loss + self.action_l2 * (actions[:, :3] ** 2).mean()
        cloning = 0.0
        if self.cloning is not None:
            term = self.cloning.loss(batch_size)
            loss = loss + term
            cloning = term.item()
        self.actor.optimizer.zero_grad()
        loss.backward()
        self.actor.optimizer.step()
        return loss.item(), cloning

    def warm_up_critic(self, updates: int) -> None:
        """Train the critic alone on the replay buffer (the demonstrations).

        The critic update of :meth:`train` with the actor fixed and the critic's target
        following.

        :param updates: the critic updates to run
        """
        for _ in range(updates):
            self.update_critic(self.replay_buffer.sample(self.batch_size,
                                                         env=self._vec_normalize_env))
            polyak_update(self.critic.parameters(), self.critic_target.parameters(), self.tau)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), 'cloning']


class DDPGCloning(TD3Cloning, DDPG):
    """:class:`TD3Cloning` on DDPG's settings: one critic, no target smoothing, no delay.

    :param policy: the policy model to use, as DDPG's
    :param env: the environment to learn from, as DDPG's
    :param kwargs: :class:`TD3Cloning`'s keyword arguments and DDPG's others
    """


ALGORITHM_CLASSES: dict[str, type[TD3Cloning]] = {'ddpg': DDPGCloning, 'td3': TD3Cloning}
