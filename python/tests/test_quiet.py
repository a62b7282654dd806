"""Mesa stays quiet from Python as it does from the simulator's commands.

Without ``XDG_RUNTIME_DIR`` Mesa prints ``error: XDG_RUNTIME_DIR is invalid or not set``
for every renderer it opens; ``pednav_gym`` gives it a private directory when the
variable is unset, as ``pednav-sim`` does (``tests/tests/sim_cli.rs`` checks that one).
Each case runs in a fresh interpreter, because the environment is read at import and
by Mesa when the first renderer opens. NumPy and Gymnasium are imported first, as in
every user's script: they start threads, after which the extension cannot set it.
"""

from __future__ import annotations

import os
import stat
import subprocess
import sys
from pathlib import Path

SCRIPT = """
import os
import numpy as np
import gymnasium as gym
import pednav_gym
env = gym.make(pednav_gym.ENV_ID, obs_mode="pixels", image_size=42, seed=0)
obs, _ = env.reset(seed=0)
obs, *_ = env.step(np.zeros(3, dtype=np.float32))
env.close()
print(os.environ.get("XDG_RUNTIME_DIR", ""))
print(float(obs.std()))
"""


def run_pixels(env: dict[str, str]) -> tuple[str, list[str]]:
    """Stderr and stdout lines of SCRIPT run with ``env``."""
    done = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return done.stderr, done.stdout.split()


def test_a_pixel_environment_without_a_runtime_dir_prints_nothing_from_mesa(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k != "XDG_RUNTIME_DIR"}
    env["TMPDIR"] = str(tmp_path)
    err, (runtime_dir, std) = run_pixels(env)
    assert "XDG_RUNTIME_DIR" not in err, err
    assert float(std) > 0, "the frame was rendered"
    expected = tmp_path / f"pednav-runtime-{os.getuid()}"
    assert runtime_dir == str(expected)
    assert stat.S_IMODE(expected.stat().st_mode) == 0o700, "the directory is private"


def test_a_runtime_dir_the_user_set_is_kept(tmp_path: Path) -> None:
    mine = tmp_path / "mine"
    mine.mkdir(mode=0o700)
    env = dict(os.environ, XDG_RUNTIME_DIR=str(mine), TMPDIR=str(tmp_path))
    err, (runtime_dir, _) = run_pixels(env)
    assert runtime_dir == str(mine)
    assert "XDG_RUNTIME_DIR" not in err, err
    assert not (tmp_path / f"pednav-runtime-{os.getuid()}").exists()
