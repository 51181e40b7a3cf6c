"""train_policy's options as one typed record, and the part of ``policy.json`` written from it.

The command line fills a :class:`TrainConfig` and the run reads nothing else; each default is
written here once (the command line shows them). The fields that describe a trained policy
go into its ``policy.json`` under their own names (:meth:`TrainConfig.policy_fields`;
``net_arch`` and ``actor_lr_share`` within its ``hyperparameters``) and are read back from one
(:meth:`TrainConfig.from_policy`); the others only steer the run (how long, how often the
curve is measured, where the data set lies). No torch here: the command line imports it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from ur_rg2_learning.dataset_demos import CAMERA_LOOK_AT, CAMERA_POSITION

ALGORITHMS = {'ddpg': 'DDPG', 'td3': 'TD3'}
HYPERPARAMETERS = 'hyperparameters'  # the policy.json entry net_arch and actor_lr_share go in


def _run_only(default: Any) -> Any:
    """Return a field that steers the run and is not written into policy.json."""
    return field(default=default, metadata={'policy': None})


def _hyperparameter(default: Any) -> Any:
    """Return a field written into policy.json's hyperparameters."""
    return field(default=default, metadata={'policy': HYPERPARAMETERS})


@dataclass
class TrainConfig:
    """What trains one policy: train_policy's options but the seeds and the output directory."""

    env_id: str
    algo: str = 'td3'
    command: str | None = None  # the train_policy command line
    demos: int = 0  # scripted pick episodes in the replay buffer
    bc: float = 0.0  # weight of the behaviour-cloning term (0: none)
    bc_fade: int = 0  # environment steps over which it falls to 0 (0: it stays)
    q_filter: bool = True
    cloning_only: bool = False  # ablation: no -Q term in the actor updates
    critic_warmup: int = 0  # critic updates on the demonstrations before the first step
    grasped_share: float = 0.0  # training episodes that start grasped
    over_ball_share: float = 0.0  # and with the open fingers round or over the ball
    clip_return: bool = False  # the critic's targets clipped to the returns the rewards allow
    action_l2: float = 0.0  # weight of the penalty on the actor's squared moves
    obs_noise_mm: float = 0.0  # Gaussian noise on the observed ball, mm per axis
    net_arch: tuple[int, ...] = _hyperparameter((256, 256))  # hidden layers of actor, critic
    actor_lr_share: float = _hyperparameter(0.1)  # the actor's learning rate / the critic's
    timesteps: int = _run_only(0)  # environment steps at most
    dataset: str | None = _run_only(None)  # a LeRobot data set's directory
    bc_epochs: int = _run_only(300)  # with a data set: epochs of cloning before RL
    camera_position: tuple[float, ...] = _run_only(CAMERA_POSITION)  # the data set's camera
    camera_look_at: tuple[float, ...] = _run_only(CAMERA_LOOK_AT)
    minutes: float = _run_only(0.0)  # wall time per seed at most (0: no bound)
    eval_every: int = _run_only(0)  # steps between curve points (0: timesteps / 20)
    eval_episodes: int = _run_only(20)  # episodes per curve point
    final_episodes: int = _run_only(100)  # held-out episodes scoring the final actor

    def policy_fields(self) -> dict[str, Any]:
        """Return the fields policy.json holds at its top level, by name."""
        values = asdict(self)
        return {f.name: values[f.name] for f in fields(self) if 'policy' not in f.metadata}

    @classmethod
    def from_policy(cls, meta: dict[str, Any]) -> TrainConfig:
        """Return the config a ``policy.json`` (its dict) was written from.

        Its other entries (the curve, the scores, ...) are ignored; fields it lacks (older
        policies, the run-only ones) take their defaults.
        """
        values: dict[str, Any] = {}
        for f in fields(cls):
            where = f.metadata.get('policy', '')
            source = meta if where == '' else meta.get(HYPERPARAMETERS, {}) if where else {}
            if f.name in source:
                values[f.name] = source[f.name]
        if 'net_arch' in values:
            values['net_arch'] = tuple(values['net_arch'])
        return cls(**values)

    def method(self) -> str:
        """Return what trains the policy, in words."""
        if self.dataset:
            name = Path(self.dataset).name
            words = (f"behaviour cloning ({self.bc_epochs} epochs) of the data set {name}'s "
                     'episodes')
            if not self.timesteps:
                return words
            words = ((words + ', then ') if self.bc_epochs else '') + (
                f"{ALGORITHMS[self.algo]} + HER with the data set {name}'s steps in the buffer")
        else:
            words = f'{ALGORITHMS[self.algo]} + HER'
        if self.demos:
            words += f' + {self.demos} scripted demos in the buffer'
        if self.bc:
            words += f" + {'Q-filtered ' if self.q_filter else ''}BC {self.bc:g}"
            if self.bc_fade:
                words += f' fading to 0 over {self.bc_fade} steps'
            if self.cloning_only:
                words += ' alone (no -Q term in the actor updates: an ablation)'
        if self.critic_warmup:
            words += f', critic warm-up {self.critic_warmup}'
        if self.grasped_share:
            words += f', {self.grasped_share:g} of episodes start grasped'
        if self.over_ball_share:
            words += f', {self.over_ball_share:g} start over the ball'
        if self.clip_return:
            words += ', returns clipped'
        if self.action_l2:
            words += f', action L2 {self.action_l2:g}'
        if self.obs_noise_mm:
            words += f', ball observed with {self.obs_noise_mm:g} mm noise'
        return words
