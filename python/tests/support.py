"""Helpers of the pednav_gym tests (pytest, NumPy and Gymnasium only), imported as `support`.

The tests run the real simulator through the extension, so they need what pednav's
Rust tests need: a graphics adapter for the pixel and render tests (a GPU, or Mesa:
``deploy/setup_system.sh``) and a release build for the oracle's planning to take
seconds (``pip install ./python`` builds one). Environments are in state mode, which
renders nothing, unless pixels are the point of the test.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import gymnasium as gym
import numpy as np

import pednav_gym


def make(**kwargs: Any) -> gym.Env:
    """``gymnasium.make`` of the crossing task with ``kwargs``."""
    return gym.make(pednav_gym.ENV_ID, **kwargs)


@contextmanager
def gymnasium_warnings() -> Iterator[list[str]]:
    """Collects the warnings Gymnasium's checkers emit (``gymnasium.logger.warn``: "WARN: …")."""
    found: list[str] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield found
    found.extend(str(w.message) for w in caught if "WARN:" in str(w.message))


def rollout(env: gym.Env, *, seed: int, steps: int, action_seed: int = 1) -> list[tuple[Any, ...]]:
    """``steps`` steps of uniformly random actions (from ``action_seed``) after
    ``reset(seed=seed)``, resetting without a seed when an episode ends; returns every
    ``(obs, reward, terminated, truncated, info)`` and reset's ``(obs, info)``."""
    actions = np.random.default_rng(action_seed)
    record: list[tuple[Any, ...]] = [env.reset(seed=seed)]
    for _ in range(steps):
        out = env.step(actions.uniform(-1.0, 1.0, size=3).astype(np.float32))
        record.append(out)
        if out[2] or out[3]:
            record.append(env.reset())
    return record


def walk_until(env: gym.Env, choose: Callable[[], np.ndarray], limit: int) -> tuple[Any, ...]:
    """Step with ``choose()`` until the episode ends or ``limit`` steps; the last step's output."""
    out: tuple[Any, ...] = ()
    for _ in range(limit):
        out = env.step(choose())
        if out[2] or out[3]:
            break
    return out
