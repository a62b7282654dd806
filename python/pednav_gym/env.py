"""``CornerEnv``: one pedestrian of pednav's built-in simulator as a Gymnasium ``Env``.

The environment is pednav-sim's, run through the Rust extension: the scene file, the
reward ``r = r_m + r_v + r_c``, the kinematic pedestrian, the renderer and the oracle
are the ones the Rust actors, ``pednav-eval`` and ``pednav-sim`` use. What this class
adds is Gymnasium's protocol: seeding through ``np_random``, ``reset(seed, options)``,
the five-tuple ``step``, ``render()`` and ``close()``.

Usage loop::

    import gymnasium as gym
    import pednav_gym  # registers "pednav/Corner-v0"

    env = gym.make("pednav/Corner-v0", obs_mode="state", t_max=2000)
    obs, info = env.reset(seed=0, options={"start": (14.0, -7.0, 180.0)})
    while True:
        obs, reward, terminated, truncated, info = env.step(env.unwrapped.oracle_action())
        if terminated or truncated:
            break

Invariant: the environment is deterministic given its seed — the start (when drawn)
and the episode seed (which drives the only randomness, the optional domain
randomisation of the look) both come from ``np_random``, and a step is a pure
function of the state and the action in Rust.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding

from pednav_gym._simulator import (
    EpisodeStarts,
    ValidationStart,
    action_space,
    checked_options,
    decode_observations,
    make_simulator,
    observation_space,
    render_rgb,
    single_info,
    validation_starts_of,
)


class CornerEnv(gym.Env[np.ndarray, np.ndarray]):
    """The crossing task of pednav's built-in simulator (the reference corner by default).

    Observation: ``uint8`` frames of shape ``(image_size, image_size, 1)`` (``obs_mode=
    "pixels"``, the paper's) or the 22 ``float32`` of the state observation
    (``obs_mode="state"``: goal in the body frame, heading, head yaw, map rewards around;
    with ``traffic`` on, 28 more: the nearest zebra's ends, its signal and time left,
    the four nearest vehicles' positions and velocities — ``pednav_sim::state_obs``).
    Action: ``Box(-1, 1, (3,), float32)`` — speed ``(a₀+1)/2 · max_speed``, yaw rate
    ``a₁ · max_yaw_rate_deg``, head yaw ``a₂ · max_head_yaw_deg`` relative to the body;
    values outside [−1, 1] are clipped, as in Rust. Reward: pednav-sim's, per decision
    step. ``terminated`` on reaching the goal, ``truncated`` at ``t_max`` steps.

    ``info`` (after ``reset`` and every ``step``): ``pose`` — ``(x m, y m, yaw °)``, a
    float64 array in the units of ``options["start"]``; ``head_yaw_deg``; ``region``
    (name of the ground under the pedestrian); ``step``; ``success`` (reached the
    goal); ``collided``; and the reward's parts ``reward_map``, ``reward_speed``,
    ``reward_collision`` (0 after a reset), whose sum in float32 is the reward.

    Keyword arguments:
        scene: a scene file or ``"built-in:<name>"``; the reference corner when None.
        image_size, obs_mode, t_max: the simulator settings of those names; None keeps
            the Rust default (84, ``"pixels"``, 8000 — the paper's training limit; the
            validation protocol uses 2000).
        seed: seeds ``np_random`` now, so that a first ``reset()`` without a seed is
            reproducible too.
        start: where episodes start when ``reset`` is given no ``options["start"]``:
            ``"first_task"`` (default), ``"fixed_start"``, ``"validation"`` (one of the
            112 validation starts, drawn from ``np_random``) or ``(x, y, yaw_deg)``.
        render_mode: None or ``"rgb_array"`` (the view for people, ``render_size``²).
        render_size: side of ``render()``'s picture in pixels (512, as ``pednav-sim view``).
        backend: graphics backend ``"auto"``, ``"vulkan"`` or ``"gl"``; None reads
            ``PEDNAV_BACKEND``, as pednav's commands do.
        **settings: any other field of the Rust ``SimConfig`` (``max_speed``, ``dt``,
            ``domain_randomization``, …), as ``--set sim.<field>=<value>`` would set it.

    Every setting and start is validated by the Rust code; a refused one raises
    :class:`~pednav_gym.PednavError` whose message names the field or pose.
    """

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(
        self,
        *,
        scene: str | os.PathLike[str] | None = None,
        image_size: int | None = None,
        obs_mode: str | None = None,
        t_max: int | None = None,
        seed: int | None = None,
        start: str | Sequence[float] = "first_task",
        render_mode: str | None = None,
        render_size: int = 512,
        backend: str | None = None,
        **settings: Any,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self._sim = make_simulator(
            1,
            scene=scene,
            backend=backend,
            settings={"image_size": image_size, "obs_mode": obs_mode, "t_max": t_max, **settings},
        )
        self.observation_space = observation_space(self._sim)
        self.action_space = action_space()
        self.render_mode = render_mode
        self._render_size = int(render_size)
        # One decision step of `dt` seconds is one frame.
        self.metadata = {**type(self).metadata, "render_fps": 1.0 / float(self._sim.settings["dt"])}
        self._starts = EpisodeStarts(self._sim, start)
        if seed is not None:
            self._np_random, self._np_random_seed = seeding.np_random(seed)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode; ``options={"start": (x, y, yaw_deg)}`` chooses its start pose."""
        super().reset(seed=seed)
        options = checked_options(options, ("start",))
        x, y, yaw_deg, episode_seed = self._starts.draw(self.np_random, options.get("start"))
        buffer, batch = self._sim.reset([(0, x, y, yaw_deg, episode_seed)])
        return self._observation(buffer), single_info(batch, 0)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        """Advance one decision step (``dt`` seconds, 0.25 by default)."""
        action = np.asarray(action, dtype=np.float32).reshape(self.action_space.shape)
        buffer, batch = self._sim.step([action.tolist()])
        return (
            self._observation(buffer),
            float(batch.reward[0]),
            bool(batch.terminated[0]),
            bool(batch.truncated[0]),
            single_info(batch, 0),
        )

    def render(self) -> np.ndarray | None:
        """The view for people at the current pose, ``(render_size, render_size, 3)`` uint8
        (grey in all three channels: the renderer is greyscale)."""
        if self.render_mode is None:
            gym.logger.warn("CornerEnv.render() draws nothing without render_mode='rgb_array'.")
            return None
        return render_rgb(self._sim, [0], self._render_size)[0]

    def oracle_action(self) -> np.ndarray:
        """The oracle's greedy action at the current state, float32 ``(3,)``.

        The oracle plans once per environment, on the first call (seconds in a release
        build), over this world's scene and settings.
        """
        return np.asarray(self._sim.oracle_actions()[0], dtype=np.float32)

    def validation_starts(self) -> list[ValidationStart]:
        """The 14 validation points × 8 yaws of this environment's scene."""
        return validation_starts_of(self._sim)

    def first_task(self) -> tuple[float, float, float]:
        """The scene's first task ``(x, y, yaw_deg)``: the curriculum's easiest start."""
        return tuple(self._sim.first_task())

    def fixed_start(self) -> tuple[float, float, float]:
        """The scene's fixed start ``(x, y, yaw_deg)``: the Non-ACL variants' start."""
        return tuple(self._sim.fixed_start())

    @property
    def settings(self) -> dict[str, Any]:
        """The simulator's settings after defaults and overrides (the Rust ``SimConfig``)."""
        return dict(self._sim.settings)

    def close(self) -> None:
        """Release the simulator (and with it the renderer). Closing twice is harmless."""
        self._sim = None

    def _observation(self, buffer: bytearray) -> np.ndarray:
        return decode_observations(self.observation_space, buffer, 1)[0]
