"""The bridge between the Rust ``Simulator`` and the Gymnasium classes.

Everything :class:`~pednav_gym.env.CornerEnv` and
:class:`~pednav_gym.vector.CornerVectorEnv` share lives here, once: building the
simulator from keyword arguments, the spaces, decoding the observation buffer,
choosing an episode's start and seed from a NumPy generator, and turning a
``StepBatch`` into an ``info``. So one vector environment of M and M single
environments with the same seeds are the same environments, step for step
(``tests/test_vector.py`` checks it against Gymnasium's ``SyncVectorEnv``).

Invariants:
- an episode draws from its environment's generator in one fixed order — the start
  (when not given), then the episode seed — whether it starts from ``reset`` or from
  an autoreset;
- every ``info`` has the same keys, with the same types, after a reset and after a
  step (:data:`INFO_FIELDS`), so Gymnasium's vector ``info`` needs no masks beyond
  "this environment reported".
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np
from gymnasium import spaces

from pednav_gym import _pednav

#: Names a ``start`` keyword may give instead of a pose.
START_CHOICES = ("first_task", "fixed_start", "validation")

#: Episode seeds are drawn below this bound (they are ``u64`` in Rust; NumPy draws int64).
_SEED_BOUND = 2**63

#: The keys of every ``info`` and the Python type of each value. ``pose`` is
#: ``(x m, y m, yaw °)`` as a float64 array, in the units of ``options["start"]``.
INFO_FIELDS: dict[str, type] = {
    "pose": np.ndarray,
    "head_yaw_deg": float,
    "region": str,
    "step": int,
    "success": bool,
    "collided": bool,
    "reward_map": float,
    "reward_speed": float,
    "reward_collision": float,
    "reward_traffic": float,
    "vehicle_hit": bool,
    "dont_walk_entry": bool,
    "pedestrian_bump": bool,
    "kerb_wait": bool,
}


class ValidationStart(NamedTuple):
    """One start of the paper's validation protocol: a validation point at one of 8 yaws."""

    point: int
    """Validation point id, 0–13 (0–7 inside the curriculum region, 8–13 outside)."""
    x: float
    """x in metres."""
    y: float
    """y in metres."""
    yaw_deg: float
    """Start yaw in degrees, 0 = east, counter-clockwise."""


def make_simulator(
    num_envs: int,
    *,
    scene: str | os.PathLike[str] | None,
    backend: str | None,
    settings: Mapping[str, Any],
) -> _pednav.Simulator:
    """A Rust simulator of ``num_envs`` environments; ``settings`` are ``SimConfig`` fields.

    Settings whose value is ``None`` keep the Rust default. Anything the Rust config
    refuses raises :class:`~pednav_gym.PednavError` naming the field.
    """
    given = {key: value for key, value in settings.items() if value is not None}
    scene_path = None if scene is None else os.fspath(scene)
    return _pednav.Simulator(num_envs, scene=scene_path, settings=given, backend=backend)


def observation_space(sim: _pednav.Simulator) -> spaces.Box:
    """One environment's observation space: ``uint8`` frames or the float32 state vector."""
    settings = sim.settings
    if settings["obs_mode"] == "pixels":
        side = int(settings["image_size"])
        return spaces.Box(0, 255, shape=(side, side, 1), dtype=np.uint8)
    low, high = sim.state_bounds()
    return spaces.Box(np.asarray(low, np.float32), np.asarray(high, np.float32), dtype=np.float32)


def action_space() -> spaces.Box:
    """One environment's action space: (speed, yaw rate, head yaw), each in [−1, 1]."""
    return spaces.Box(_pednav.ACTION_LOW, _pednav.ACTION_HIGH, shape=(_pednav.ACTION_DIM,), dtype=np.float32)


def decode_observations(space: spaces.Box, buffer: bytearray, count: int) -> np.ndarray:
    """The ``count`` observations in ``buffer`` as one array of shape ``(count, *space.shape)``.

    The array is a writable view of the new ``bytearray`` of this call: no copy, and no
    memory shared with any earlier observation.
    """
    return np.frombuffer(buffer, dtype=space.dtype).reshape((count, *space.shape))


def render_rgb(sim: _pednav.Simulator, envs: Sequence[int], size: int) -> list[np.ndarray]:
    """The view for people of each environment of ``envs`` as ``(size, size, 3)`` uint8.

    The renderer is greyscale, so the grey level is repeated in the three channels.
    """
    buffer = sim.render_people(list(envs), size)
    grey = np.frombuffer(buffer, dtype=np.uint8).reshape(len(envs), size, size, 1)
    return [np.repeat(view, 3, axis=2) for view in grey]


def validation_starts_of(sim: _pednav.Simulator) -> list[ValidationStart]:
    """The validation starts of the simulator's scene."""
    return [ValidationStart(*start) for start in sim.validation_starts()]


class EpisodeStarts:
    """Chooses where each episode starts, from a ``start`` keyword.

    ``start`` is ``"first_task"`` (the scene's easiest start, 6 m from the goal and
    facing it in the reference corner), ``"fixed_start"`` (the Non-ACL variants' start,
    validation point 3), ``"validation"`` (one of the 112 validation starts, uniformly
    from the environment's generator) or a pose ``(x, y, yaw_deg)``.
    """

    def __init__(self, sim: _pednav.Simulator, start: str | Sequence[float]) -> None:
        self._fixed: tuple[float, float, float] | None
        self._choices: list[ValidationStart] = []
        if isinstance(start, str):
            if start == "first_task":
                self._fixed = sim.first_task()
            elif start == "fixed_start":
                self._fixed = sim.fixed_start()
            elif start == "validation":
                self._fixed = None
                self._choices = validation_starts_of(sim)
            else:
                raise ValueError(f"start must be one of {START_CHOICES} or (x, y, yaw_deg), got {start!r}")
        else:
            self._fixed = pose_of(start, "start")

    def draw(
        self, rng: np.random.Generator, requested: Sequence[float] | None = None
    ) -> tuple[float, float, float, int]:
        """The next episode's ``(x, y, yaw_deg, episode_seed)``: the ``requested`` pose
        when given, else this chooser's; the seed always comes from ``rng``."""
        if requested is not None:
            x, y, yaw_deg = pose_of(requested, 'options["start"]')
        elif self._fixed is not None:
            x, y, yaw_deg = self._fixed
        else:
            choice = self._choices[int(rng.integers(len(self._choices)))]
            x, y, yaw_deg = choice.x, choice.y, choice.yaw_deg
        seed = int(rng.integers(_SEED_BOUND, dtype=np.int64))
        return x, y, yaw_deg, seed


def pose_of(value: Sequence[float], name: str) -> tuple[float, float, float]:
    """``value`` as an ``(x, y, yaw_deg)`` pose of three finite numbers."""
    try:
        x, y, yaw_deg = (float(v) for v in value)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be (x, y, yaw_deg), got {value!r}") from error
    return x, y, yaw_deg


def checked_options(options: Mapping[str, Any] | None, allowed: Sequence[str]) -> dict[str, Any]:
    """A copy of the ``reset`` options, refusing keys the environment does not read."""
    options = dict(options or {})
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise ValueError(f"unknown reset options {unknown}; this environment reads {list(allowed)}")
    return options


def single_info(batch: _pednav.StepBatch, env: int) -> dict[str, Any]:
    """The ``info`` of environment ``env`` in ``batch``, with Python scalars (see :data:`INFO_FIELDS`)."""
    return {
        "pose": np.array([batch.x[env], batch.y[env], batch.yaw_deg[env]], dtype=np.float64),
        "head_yaw_deg": float(batch.head_yaw_deg[env]),
        "region": str(batch.region[env]),
        "step": int(batch.step[env]),
        "success": bool(batch.terminated[env]) and not bool(batch.vehicle_hit[env]),
        "collided": bool(batch.collided[env]),
        "reward_map": float(batch.reward_map[env]),
        "reward_speed": float(batch.reward_speed[env]),
        "reward_collision": float(batch.reward_collision[env]),
        "reward_traffic": float(batch.reward_traffic[env]),
        "vehicle_hit": bool(batch.vehicle_hit[env]),
        "dont_walk_entry": bool(batch.dont_walk_entry[env]),
        "pedestrian_bump": bool(batch.pedestrian_bump[env]),
        "kerb_wait": bool(batch.kerb_wait[env]),
    }


def vector_info(batch: _pednav.StepBatch, reported: np.ndarray) -> dict[str, Any]:
    """The vector ``info`` of ``batch``: one array per key of :data:`INFO_FIELDS` and
    the mask ``_key`` of the environments that reported, laid out as Gymnasium's
    ``VectorEnv._add_info`` lays out the ``info`` of each environment.

    Entries of environments that did not report are zeros (``None`` for ``region``).
    """
    reported = np.asarray(reported, dtype=np.bool_)
    columns: dict[str, np.ndarray] = {
        "pose": np.stack(
            [np.asarray(batch.x, np.float64), np.asarray(batch.y, np.float64), np.asarray(batch.yaw_deg, np.float64)],
            axis=1,
        ),
        "head_yaw_deg": np.asarray(batch.head_yaw_deg, dtype=np.float64),
        "region": np.array(batch.region, dtype=object),
        "step": np.asarray(batch.step, dtype=np.int64),
        "success": np.asarray(batch.terminated, dtype=np.bool_) & ~np.asarray(batch.vehicle_hit, dtype=np.bool_),
        "collided": np.asarray(batch.collided, dtype=np.bool_),
        "reward_map": np.asarray(batch.reward_map, dtype=np.float64),
        "reward_speed": np.asarray(batch.reward_speed, dtype=np.float64),
        "reward_collision": np.asarray(batch.reward_collision, dtype=np.float64),
        "reward_traffic": np.asarray(batch.reward_traffic, dtype=np.float64),
        "vehicle_hit": np.asarray(batch.vehicle_hit, dtype=np.bool_),
        "dont_walk_entry": np.asarray(batch.dont_walk_entry, dtype=np.bool_),
        "pedestrian_bump": np.asarray(batch.pedestrian_bump, dtype=np.bool_),
        "kerb_wait": np.asarray(batch.kerb_wait, dtype=np.bool_),
    }
    info: dict[str, Any] = {}
    for key, column in columns.items():
        column[~reported] = None if column.dtype == object else 0
        info[key] = column
        info[f"_{key}"] = reported.copy()
    return info
