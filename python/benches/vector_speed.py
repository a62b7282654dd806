"""Env steps per wall-second from Python against the simulator's own bench, in one run.

    python python/benches/vector_speed.py [--envs 16] [--seconds 20] [--image-size 84]

Runs ``pednav-sim bench --envs N`` (the Rust figure: physics step + render + readback +
copy of every frame, per wall-second) and then the same work from Python: a
``CornerVectorEnv`` of N pixel environments stepped with random actions for
``--seconds`` (observations decoded into NumPy, infos built, autoresets included), and
prints both rates and their ratio (the package's goal: ≥ 0.8). Both run one after the
other on the same machine in the same minute, so only the ratio is meaningful.
``PEDNAV_SIM`` names the ``pednav-sim`` binary (default: ``target/release/pednav-sim``
of this repository).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import pednav_gym


def rust_full_rate(binary: str, envs: int) -> float:
    """``full st/s`` of ``pednav-sim bench`` at ``envs`` environments."""
    out = subprocess.run([binary, "bench", "--envs", str(envs)], check=True, capture_output=True, text=True).stdout
    for line in out.splitlines():
        cells = line.split()
        if cells and cells[0] == str(envs) and len(cells) >= 7:
            return float(cells[4])
    raise RuntimeError(f"no row for {envs} envs in the output of {binary} bench:\n{out}")


def python_rate(envs: int, seconds: float, image_size: int) -> tuple[float, int]:
    """Env steps per wall-second of the vector env, and the steps taken."""
    vec = gym.make_vec(
        pednav_gym.ENV_ID, num_envs=envs, vectorization_mode="vector_entry_point",
        obs_mode="pixels", image_size=image_size, t_max=2000, start="validation",
    )
    rng = np.random.default_rng(0)
    vec.reset(seed=0)
    for _ in range(5):  # warm-up: the renderer's first frames
        vec.step(rng.uniform(-1, 1, size=(envs, 3)).astype(np.float32))
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        vec.step(rng.uniform(-1, 1, size=(envs, 3)).astype(np.float32))
        steps += envs
    rate = steps / (time.perf_counter() - start)
    vec.close()
    return rate, steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, default=16, help="environments (default 16)")
    parser.add_argument("--seconds", type=float, default=20.0, help="seconds of Python stepping (default 20)")
    parser.add_argument("--image-size", type=int, default=84, help="observation side (default 84)")
    args = parser.parse_args()
    repo = Path(__file__).resolve().parents[2]
    binary = os.environ.get("PEDNAV_SIM", str(repo / "target" / "release" / "pednav-sim"))
    if args.image_size != 84:
        raise SystemExit("pednav-sim bench renders 84² views: compare at --image-size 84")
    rust = rust_full_rate(binary, args.envs)
    py, steps = python_rate(args.envs, args.seconds, args.image_size)
    print(f"envs {args.envs}, {args.image_size}² pixels, random actions")
    print(f"pednav-sim bench full st/s: {rust:.0f}")
    print(f"python vector env st/s:     {py:.0f} ({steps} steps)")
    print(f"python / rust: {py / rust:.2f} (goal >= 0.8)")


if __name__ == "__main__":
    main()
