"""A trained policy as the run path uses it: the actor network in NumPy, no torch.

A policy directory holds ``actor.npz`` (the layers' weights and biases, ``w0``, ``b0``, ...;
ReLU between layers, tanh after the last, as Stable-Baselines3's DDPG actor) and
``policy.json`` (the environment id, the order in which the observation's parts are
concatenated, the action bounds and how it was trained). ``train_policy`` writes both.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
import importlib.resources
import json
import os
from pathlib import Path
import tempfile
from typing import Any, BinaryIO

import numpy as np

ACTOR_FILE = 'actor.npz'
META_FILE = 'policy.json'
# The policies that come with the package.
SHIPPED = ('reach', 'pick', 'pick_cloned', 'pick_demos')


def shipped_policy(name: str = 'reach') -> str:
    """Return the directory of a policy that comes with the package (one of SHIPPED)."""
    return str(importlib.resources.files('ur_rg2_learning').joinpath('policies', name))


class PolicyError(ValueError):
    """A policy directory cannot be used; str() says why."""


class Actor:
    """A deterministic policy: observation dict -> action, in NumPy."""

    def __init__(self, layers: list[tuple[np.ndarray, np.ndarray]], meta: dict[str, Any]) -> None:
        self.layers = layers
        self.meta = meta
        self.keys: list[str] = list(meta['observation_keys'])
        self.low = np.asarray(meta['action_low'], dtype=np.float64)
        self.high = np.asarray(meta['action_high'], dtype=np.float64)

    @property
    def env_id(self) -> str:
        """The Gymnasium id of the environment the policy was trained on."""
        return self.meta['env_id']

    @classmethod
    def load(cls, directory: str | os.PathLike) -> Actor:
        """Read a policy directory; PolicyError when it is missing or inconsistent."""
        directory = Path(directory)
        try:
            meta = json.loads((directory / META_FILE).read_text())
            with np.load(directory / ACTOR_FILE) as data:
                count = len([name for name in data.files if name.startswith('w')])
                layers = [(data[f'w{i}'].astype(np.float64), data[f'b{i}'].astype(np.float64))
                          for i in range(count)]
            actor = cls(layers, meta)
        except (OSError, KeyError, ValueError, TypeError) as error:
            raise PolicyError(f'no usable policy in {directory}: {error}') from None
        if not layers or layers[-1][0].shape[0] != actor.low.shape[0]:
            raise PolicyError(f'no usable policy in {directory}: the layers do not fit the '
                              'action size')
        return actor

    def save(self, directory: str | os.PathLike) -> None:
        """Write ``actor.npz`` and ``policy.json`` into ``directory``, each atomically."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        arrays = {}
        for i, (weight, bias) in enumerate(self.layers):
            arrays[f'w{i}'], arrays[f'b{i}'] = weight.astype(np.float32), bias.astype(np.float32)
        write_atomically(directory / ACTOR_FILE, lambda f: np.savez(f, **arrays))
        write_atomically(directory / META_FILE,
                         lambda f: f.write(json.dumps(self.meta, indent=2).encode() + b'\n'))

    def __call__(self, observation: Mapping[str, np.ndarray]) -> np.ndarray:
        """Return the action for one observation dict."""
        x = np.concatenate([np.asarray(observation[key], dtype=np.float64).ravel()
                            for key in self.keys])
        for weight, bias in self.layers[:-1]:
            x = np.maximum(weight @ x + bias, 0.0)
        weight, bias = self.layers[-1]
        squashed = np.tanh(weight @ x + bias)
        return self.low + (squashed + 1.0) * 0.5 * (self.high - self.low)


def write_atomically(path: Path, write: Callable[[BinaryIO], object]) -> None:
    """Write ``path`` whole or not at all: ``write(file)`` into a temporary file, then rename."""
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f'.{path.name}.')
    try:
        with os.fdopen(handle, 'wb') as f:
            write(f)
        os.chmod(temporary, 0o644)  # mkstemp's 0600 would hide it from other users
        os.replace(temporary, path)
    except BaseException:
        os.unlink(temporary)
        raise
