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
import stat
import tempfile

from gymnasium.envs.registration import register, registry


def _give_mesa_a_runtime_dir() -> None:
    """Set ``XDG_RUNTIME_DIR`` to a private directory when it is unset or not a directory.

    Without it Mesa prints ``error: XDG_RUNTIME_DIR is invalid or not set`` for every
    renderer it opens. The simulator's commands set the same directory
    (``<tmp>/pednav-runtime-<uid>``, mode 0700) at start, while they are one thread;
    the extension module cannot — by the time it loads, NumPy's and Gymnasium's
    imports have started threads, and the simulator never calls ``setenv`` beside
    another thread — so the package does it here, through ``os.environ`` as Python
    programs do, before the extension loads and long before a renderer opens.
    """
    current = os.environ.get("XDG_RUNTIME_DIR")
    if current and os.path.isdir(current):
        return
    path = os.path.join(tempfile.gettempdir(), f"pednav-runtime-{os.getuid()}")
    try:
        os.makedirs(path, mode=0o700, exist_ok=True)
        info = os.lstat(path)
    except OSError:
        return  # Mesa will say so itself; rendering still works
    if stat.S_ISDIR(info.st_mode) and info.st_uid == os.getuid() and info.st_mode & 0o077 == 0:
        os.environ["XDG_RUNTIME_DIR"] = path


_give_mesa_a_runtime_dir()

from pednav_gym import _pednav  # noqa: E402  (after the runtime directory is set)
from pednav_gym._pednav import PednavError  # noqa: E402
from pednav_gym._simulator import ValidationStart  # noqa: E402
from pednav_gym.env import CornerEnv  # noqa: E402
from pednav_gym.vector import CornerVectorEnv  # noqa: E402

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
