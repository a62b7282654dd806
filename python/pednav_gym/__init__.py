"""pednav_gym — pednav's built-in simulator as Gymnasium environments.

Importing the package registers ``pednav/Corner-v0`` with Gymnasium, for
``gymnasium.make`` (:class:`CornerEnv`) and ``gymnasium.make_vec`` (with
``vectorization_mode="vector_entry_point"``: :class:`CornerVectorEnv`)::

    import gymnasium as gym
    import pednav_gym

    env = gym.make("pednav/Corner-v0", image_size=84, obs_mode="pixels", t_max=2000, seed=0)

The simulation itself — scene files, reward, physics, renderer, oracle — is the Rust
crate ``pednav-sim``, reached through the extension module ``pednav_gym._pednav``.
See ``python/README.md``.
"""

from __future__ import annotations

import os

from gymnasium.envs.registration import register, registry

from pednav_gym import _pednav
from pednav_gym._pednav import PednavError
from pednav_gym._simulator import ValidationStart
from pednav_gym.env import CornerEnv
from pednav_gym.vector import CornerVectorEnv

#: The Gymnasium id of the crossing task.
ENV_ID = "pednav/Corner-v0"

__all__ = ["ENV_ID", "CornerEnv", "CornerVectorEnv", "PednavError", "ValidationStart", "validation_starts"]


def validation_starts(scene: str | os.PathLike[str] | None = None) -> list[ValidationStart]:
    """The paper's validation starts of ``scene``: its 14 validation points × 8 yaws.

    ``scene`` is a scene file or ``"built-in:<name>"`` (the reference corner when None).
    The list is in the protocol's order — points outer, yaws (0°, 45°, −45°, 90°, −90°,
    135°, −135°, 180°) inner — as ``pednav-eval`` runs it; pass an entry's
    ``(x, y, yaw_deg)`` as ``reset(options={"start": ...})``.
    """
    scene_path = None if scene is None else os.fspath(scene)
    return [ValidationStart(*start) for start in _pednav.validation_starts(scene_path)]


if ENV_ID not in registry:
    register(
        id=ENV_ID,
        entry_point="pednav_gym.env:CornerEnv",
        vector_entry_point="pednav_gym.vector:CornerVectorEnv",
    )
