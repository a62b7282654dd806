"""Stable-Baselines3 SAC on pednav's state observation — an example run by hand, not in CI.

    pip install ./python stable-baselines3        # from the repository root
    python python/examples/sb3_sac_state.py --steps 100000 --seed 0

Trains SB3's SAC (its defaults, γ = 0.99 as the paper's) from the 22-float state
observation on the crossing task, starting every training episode at ``--start``
(the first task by default: 6 m from the goal, facing it). It then runs the
deterministic policy from each evaluation start with the validation protocol's
``t_max = 2000`` and prints, per start and overall, the undiscounted and discounted
(γ = 0.99) return and whether it reached the goal, beside the oracle's from the same
starts. The state observation is privileged (it is not the paper's pixel task): this is
a quick way to see an off-the-shelf agent learn the simulator's task.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
from stable_baselines3 import SAC

import pednav_gym

GAMMA = 0.99


@dataclass
class Episode:
    """One evaluation episode's outcome."""

    undiscounted: float
    discounted: float
    steps: int
    success: bool


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=100_000, help="SAC environment steps")
    parser.add_argument("--seed", type=int, default=0, help="seed of the environment and of SAC")
    parser.add_argument("--start", default="first_task", help="training starts: first_task, fixed_start, validation")
    parser.add_argument("--train-t-max", type=int, default=500, help="episode limit in training (steps)")
    parser.add_argument(
        "--eval", default="first_task,fixed_start", help="evaluation starts: first_task, fixed_start and/or validation"
    )
    parser.add_argument("--scene", default=None, help="scene file or built-in:<name> (default: the reference corner)")
    return parser.parse_args()


def evaluation_starts(env: gym.Env, names: str) -> list[tuple[str, tuple[float, float, float]]]:
    """The (label, pose) of each evaluation start named in ``names``."""
    sim = env.unwrapped
    starts = []
    for name in names.split(","):
        if name == "validation":
            starts += [(f"point {s.point} yaw {s.yaw_deg:+.0f}", (s.x, s.y, s.yaw_deg)) for s in sim.validation_starts()]
        elif name in ("first_task", "fixed_start"):
            starts.append((name, getattr(sim, name)()))
        else:
            raise SystemExit(f"--eval: {name!r} is not first_task, fixed_start or validation")
    return starts


def run_episode(env: gym.Env, start: tuple[float, float, float], act) -> Episode:
    """One episode from ``start`` with ``act(obs) -> action``."""
    obs, _ = env.reset(options={"start": start})
    undiscounted, discounted, weight = 0.0, 0.0, 1.0
    while True:
        obs, reward, terminated, truncated, info = env.step(act(obs))
        undiscounted += reward
        discounted += weight * reward
        weight *= GAMMA
        if terminated or truncated:
            return Episode(undiscounted, discounted, info["step"], bool(info["success"]))


def main() -> None:
    args = parse_args()
    train_env = gym.make(
        pednav_gym.ENV_ID, obs_mode="state", t_max=args.train_t_max, start=args.start, seed=args.seed, scene=args.scene
    )
    model = SAC("MlpPolicy", train_env, gamma=GAMMA, seed=args.seed, verbose=1)
    began = time.monotonic()
    model.learn(total_timesteps=args.steps)
    print(f"trained {args.steps} steps in {time.monotonic() - began:.0f} s")

    eval_env = gym.make(pednav_gym.ENV_ID, obs_mode="state", t_max=2000, seed=args.seed, scene=args.scene)
    oracle = eval_env.unwrapped.oracle_action
    rows = []
    for label, start in evaluation_starts(eval_env, args.eval):
        sac = run_episode(eval_env, start, lambda obs: model.predict(obs, deterministic=True)[0])
        best = run_episode(eval_env, start, lambda obs: oracle())
        rows.append((sac, best))
        print(
            f"{label:>24}: SAC return {sac.undiscounted:8.2f} (γ {sac.discounted:7.2f}) {sac.steps:5d} steps "
            f"{'goal' if sac.success else 'no goal':>7} | oracle {best.undiscounted:8.2f} (γ {best.discounted:7.2f})"
        )
    sac_runs = [sac for sac, _ in rows]
    print(
        f"mean over {len(rows)} starts: SAC return {np.mean([e.undiscounted for e in sac_runs]):.2f}, "
        f"discounted {np.mean([e.discounted for e in sac_runs]):.2f}, "
        f"success {np.mean([e.success for e in sac_runs]):.0%}; "
        f"oracle discounted {np.mean([b.discounted for _, b in rows]):.2f}"
    )
    train_env.close()
    eval_env.close()


if __name__ == "__main__":
    main()
