"""The validation helper and the start choices, against the paper's protocol (§V-C:
14 validation points × 8 yaws) and the points of docs/simulator.md."""

from __future__ import annotations

import numpy as np
import pytest
from support import make

import pednav_gym

#: The protocol's yaws, degrees (paper §V-C; `pednav_experiments::protocol::YAWS_DEG`).
PAPER_YAWS_DEG = {0.0, 45.0, -45.0, 90.0, -90.0, 135.0, -135.0, 180.0}


def test_the_validation_helper_gives_14_points_at_8_yaws() -> None:
    starts = pednav_gym.validation_starts()
    assert len(starts) == 112
    assert [s.point for s in starts] == [p for p in range(14) for _ in range(8)]
    for point in range(14):
        at_point = [s for s in starts if s.point == point]
        assert {s.yaw_deg for s in at_point} == PAPER_YAWS_DEG
        assert len({(s.x, s.y) for s in at_point}) == 1
    # Points 0 and 7 of docs/simulator.md's table.
    assert (starts[0].x, starts[0].y) == (5.5, 7.0)
    assert (starts[7 * 8].x, starts[7 * 8].y) == (32.0, -7.0)


def test_the_helper_reads_the_scene_it_is_given_and_the_env_its_own() -> None:
    plain = pednav_gym.validation_starts("built-in:corner_plain")
    assert [tuple(s) for s in plain] == [tuple(s) for s in pednav_gym.validation_starts()]
    env = make(obs_mode="state")
    assert env.unwrapped.validation_starts() == pednav_gym.validation_starts()
    env.close()


def test_every_validation_start_is_a_start_the_env_accepts() -> None:
    env = make(obs_mode="state")
    for start in pednav_gym.validation_starts():
        _, info = env.reset(options={"start": (start.x, start.y, start.yaw_deg)})
        np.testing.assert_allclose(info["pose"][:2], (start.x, start.y), atol=1e-4)
    env.close()


def test_start_validation_draws_validation_starts_from_the_seed() -> None:
    allowed = {(s.x, s.y, s.yaw_deg) for s in pednav_gym.validation_starts()}
    env = make(obs_mode="state", start="validation")
    drawn = set()
    for episode in range(30):
        _, info = env.reset(seed=episode)
        x, y, yaw = info["pose"]
        match = [a for a in allowed if abs(a[0] - x) < 1e-4 and abs(a[1] - y) < 1e-4 and _same_yaw(a[2], yaw)]
        assert match, f"episode {episode} started at {info['pose']}, not a validation start"
        drawn.add(match[0])
    assert len(drawn) > 10, "30 seeds draw many different starts"
    env.close()


@pytest.mark.parametrize(("start", "pose"), [("first_task", (12.0, 7.0, 0.0)), ("fixed_start", (14.0, -7.0, 180.0))])
def test_named_starts_are_the_scenes(start: str, pose: tuple[float, float, float]) -> None:
    env = make(obs_mode="state", start=start)
    _, info = env.reset(seed=0)
    np.testing.assert_allclose(info["pose"][:2], pose[:2], atol=1e-4)
    assert _same_yaw(info["pose"][2], pose[2])
    env.close()


def test_an_unknown_start_name_is_refused() -> None:
    with pytest.raises(ValueError, match="first_task"):
        make(obs_mode="state", start="somewhere")


def _same_yaw(a: float, b: float) -> bool:
    return abs((a - b + 180.0) % 360.0 - 180.0) < 1e-3
