"""``CornerVectorEnv``: M pedestrians stepped in one call, as a Gymnasium ``VectorEnv``.

One Rust ``Simulator`` holds the M environments (one world, one renderer), so a
``step`` is one call into Rust — with the GIL released while it steps, renders all M
views in one GPU submission and reads them back once — instead of M calls. Apart from
speed it behaves as ``gymnasium.vector.SyncVectorEnv`` over M :class:`CornerEnv` with
the same seeds: the same observations, rewards, flags and infos, autoreset included
(``tests/test_vector.py`` checks it step by step).

Usage loop::

    import gymnasium as gym
    import pednav_gym

    envs = gym.make_vec("pednav/Corner-v0", num_envs=16, vectorization_mode="vector_entry_point",
                        obs_mode="state", start="validation")
    obs, infos = envs.reset(seed=0)
    for _ in range(1000):
        obs, rewards, terminated, truncated, infos = envs.step(envs.action_space.sample())

Autoreset (``metadata["autoreset_mode"]``): ``NEXT_STEP`` (Gymnasium's default) — an
environment whose episode ended restarts at the next ``step``, which ignores its action
and reports the new episode's first observation with reward 0 — or ``DISABLED`` —
ended environments must be restarted with ``reset(options={"reset_mask": mask})``.

Invariant: environment ``i`` draws its starts and episode seeds from its own generator,
seeded with ``seed + i`` by ``reset(seed=seed)`` (or ``seed[i]`` from a list), as
``SyncVectorEnv`` seeds its sub-environments.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from pednav_gym._simulator import (
    EpisodeStarts,
    ValidationStart,
    action_space,
    checked_options,
    decode_observations,
    make_simulator,
    observation_space,
    render_rgb,
    validation_starts_of,
    vector_info,
)

_AUTORESET_MODES = (AutoresetMode.NEXT_STEP, AutoresetMode.DISABLED)


class CornerVectorEnv(VectorEnv):
    """M environments of :class:`~pednav_gym.env.CornerEnv`, stepped and rendered as one batch.

    Takes ``num_envs`` and every keyword of :class:`~pednav_gym.env.CornerEnv` (with
    ``seed`` seeding environment ``i`` with ``seed + i``), plus ``autoreset_mode``.
    ``reset`` options: ``reset_mask`` (a bool array of shape ``(num_envs,)``: restart
    only those), ``start`` (one ``(x, y, yaw_deg)`` for every restarted environment) or
    ``starts`` (one pose or None per environment). ``info`` holds the keys of
    ``CornerEnv``'s, batched, each with its ``_key`` mask, as Gymnasium batches them.
    """

    metadata: dict[str, Any] = {
        "render_modes": ["rgb_array"],
        "render_fps": 4,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        num_envs: int,
        *,
        scene: str | os.PathLike[str] | None = None,
        image_size: int | None = None,
        obs_mode: str | None = None,
        t_max: int | None = None,
        seed: int | Sequence[int] | None = None,
        start: str | Sequence[float] = "first_task",
        render_mode: str | None = None,
        render_size: int = 512,
        backend: str | None = None,
        autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP,
        **settings: Any,
    ) -> None:
        mode = AutoresetMode(autoreset_mode)
        if mode not in _AUTORESET_MODES:
            raise ValueError(f"autoreset_mode must be one of {[m.value for m in _AUTORESET_MODES]}, got {mode.value}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self._sim = make_simulator(
            num_envs,
            scene=scene,
            backend=backend,
            settings={"image_size": image_size, "obs_mode": obs_mode, "t_max": t_max, **settings},
        )
        self.num_envs = int(self._sim.num_envs)
        self.single_observation_space = observation_space(self._sim)
        self.single_action_space = action_space()
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.render_mode = render_mode
        self._render_size = int(render_size)
        self.metadata = {
            **type(self).metadata,
            "render_fps": 1.0 / float(self._sim.settings["dt"]),
            "autoreset_mode": mode,
        }
        self._starts = EpisodeStarts(self._sim, start)
        self._generators: list[np.random.Generator | None] = [None] * self.num_envs
        self._generator_seeds: list[int | None] = [None] * self.num_envs
        # Environments whose episode ended at the last step (they restart at the next).
        self._ended = np.zeros(self.num_envs, dtype=np.bool_)
        if seed is not None:
            for env, env_seed in enumerate(_seed_list(seed, self.num_envs)):
                self._seed(env, env_seed)

    @property
    def np_random(self) -> tuple[np.random.Generator, ...]:
        """The generator of each environment (created unseeded on first use)."""
        return tuple(self._generator(env) for env in range(self.num_envs))

    @property
    def np_random_seed(self) -> tuple[int, ...]:
        """The seed of each environment's generator."""
        return tuple(self._generator_seed(env) for env in range(self.num_envs))

    def reset(
        self,
        *,
        seed: int | Sequence[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Restart every environment, or those of ``options["reset_mask"]``."""
        seeds = _seed_list(seed, self.num_envs)
        options = checked_options(options, ("reset_mask", "start", "starts"))
        mask = _reset_mask(options.get("reset_mask"), self.num_envs)
        requested = _requested_starts(options, self.num_envs)
        starts = []
        for env in map(int, np.flatnonzero(mask)):
            if seeds[env] is not None:
                self._seed(env, seeds[env])
            starts.append((env, *self._starts.draw(self._generator(env), requested[env])))
        buffer, batch = self._sim.reset(starts)
        self._ended[mask] = False
        return self._observations(buffer), vector_info(batch, mask)

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every environment (restarting, in ``NEXT_STEP`` mode, those that ended)."""
        actions = np.asarray(actions, dtype=np.float32).reshape(self.action_space.shape)
        restarts = []
        if self.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP:
            for env in map(int, np.flatnonzero(self._ended)):
                restarts.append((env, *self._starts.draw(self._generator(env))))
        buffer, batch = self._sim.step(actions.tolist(), restarts)
        terminated = np.asarray(batch.terminated, dtype=np.bool_)
        truncated = np.asarray(batch.truncated, dtype=np.bool_)
        self._ended = terminated | truncated
        rewards = np.asarray(batch.reward, dtype=np.float64)
        infos = vector_info(batch, np.ones(self.num_envs, dtype=np.bool_))
        return self._observations(buffer), rewards, terminated, truncated, infos

    def render(self) -> tuple[np.ndarray, ...] | None:
        """The view for people of every environment, each ``(render_size, render_size, 3)`` uint8."""
        if self.render_mode is None:
            gym.logger.warn("CornerVectorEnv.render() draws nothing without render_mode='rgb_array'.")
            return None
        return tuple(render_rgb(self._sim, range(self.num_envs), self._render_size))

    def oracle_actions(self) -> np.ndarray:
        """The oracle's greedy action in every environment, float32 ``(num_envs, 3)``
        (planned once, on the first call)."""
        return np.asarray(self._sim.oracle_actions(), dtype=np.float32).reshape(self.action_space.shape)

    def validation_starts(self) -> list[ValidationStart]:
        """The 14 validation points × 8 yaws of the scene."""
        return validation_starts_of(self._sim)

    @property
    def settings(self) -> dict[str, Any]:
        """The simulator's settings after defaults and overrides (the Rust ``SimConfig``)."""
        return dict(self._sim.settings)

    def close_extras(self, **kwargs: Any) -> None:
        """Release the simulator and its renderers."""
        self._sim = None

    def _observations(self, buffer: bytearray) -> np.ndarray:
        return decode_observations(self.single_observation_space, buffer, self.num_envs)

    def _seed(self, env: int, seed: int) -> None:
        self._generators[env], self._generator_seeds[env] = seeding.np_random(seed)

    def _generator(self, env: int) -> np.random.Generator:
        generator = self._generators[env]
        if generator is None:
            generator, self._generator_seeds[env] = seeding.np_random()
            self._generators[env] = generator
        return generator

    def _generator_seed(self, env: int) -> int:
        self._generator(env)
        seed = self._generator_seeds[env]
        assert seed is not None
        return seed


def _seed_list(seed: int | Sequence[int | None] | None, count: int) -> list[int | None]:
    """Per-environment seeds as ``SyncVectorEnv`` reads them: None, ``seed + i``, or a list."""
    if seed is None:
        return [None] * count
    if isinstance(seed, (int, np.integer)):
        return [int(seed) + env for env in range(count)]
    seeds = list(seed)
    if len(seeds) != count:
        raise ValueError(f"a list of seeds must have one per environment ({count}), got {len(seeds)}")
    return seeds


def _reset_mask(mask: Any, count: int) -> np.ndarray:
    """The environments a reset restarts: all, or ``mask`` (checked as ``SyncVectorEnv`` checks it)."""
    if mask is None:
        return np.ones(count, dtype=np.bool_)
    if not isinstance(mask, np.ndarray) or mask.dtype != np.bool_:
        raise TypeError(f"options['reset_mask'] must be a numpy bool array, got {mask!r}")
    if mask.shape != (count,):
        raise ValueError(f"options['reset_mask'] must have shape ({count},), got {mask.shape}")
    if not mask.any():
        raise ValueError("options['reset_mask'] must restart at least one environment")
    return mask.copy()


def _requested_starts(options: dict[str, Any], count: int) -> list[Sequence[float] | None]:
    """The start pose asked for each environment, None where the environment draws its own."""
    if "start" in options and "starts" in options:
        raise ValueError("give options['start'] (one pose for all) or options['starts'] (one per environment), not both")
    if "starts" in options:
        starts = list(options["starts"])
        if len(starts) != count:
            raise ValueError(f"options['starts'] must hold one pose (or None) per environment ({count}), got {len(starts)}")
        return starts
    return [options.get("start")] * count
