"""``render()`` (the 512² view for people) and the oracle's action, through Gymnasium."""

from __future__ import annotations

import numpy as np
import pytest
from support import gymnasium_warnings, make, walk_until


def test_render_is_the_512_view_for_people_in_rgb() -> None:
    env = make(obs_mode="state", render_mode="rgb_array")
    env.reset(seed=0)
    view = env.render()
    assert view.shape == (512, 512, 3) and view.dtype == np.uint8
    # The renderer is greyscale: the grey level is repeated in the three channels.
    assert np.array_equal(view[..., 0], view[..., 1]) and np.array_equal(view[..., 0], view[..., 2])
    assert view.std() > 0, "a view of the crossing is not one flat grey"
    env.step(np.array([0.0, 1.0, 0.0], dtype=np.float32))
    assert not np.array_equal(env.render(), view), "turning changes the view"
    env.close()


def test_the_view_for_people_follows_the_observation_renderers_camera() -> None:
    # The same pose drawn at 84² (the observation) and at 84² for people is the same picture.
    env = make(image_size=84, render_mode="rgb_array", render_size=84)
    obs, _ = env.reset(seed=0, options={"start": (14.0, -7.0, 135.0)})
    view = env.render()
    difference = np.abs(view[..., 0].astype(np.int16) - obs[..., 0].astype(np.int16)).mean()
    assert difference < 0.5, difference
    env.close()


def test_render_without_a_render_mode_warns_and_draws_nothing() -> None:
    env = make(obs_mode="state")
    env.reset(seed=0)
    with gymnasium_warnings() as warned:
        assert env.unwrapped.render() is None
    assert any("render_mode" in w for w in warned)
    env.close()


@pytest.fixture(scope="module")
def oracle_env():
    env = make(obs_mode="state", t_max=2000)
    yield env
    env.close()


def test_the_oracle_reaches_the_goal_from_the_first_task(oracle_env) -> None:
    oracle_env.reset(seed=0, options={"start": (12.0, 7.0, 0.0)})
    action = oracle_env.unwrapped.oracle_action()
    assert action.shape == (3,) and action.dtype == np.float32 and np.all(np.abs(action) <= 1.0)
    _, reward, terminated, truncated, info = walk_until(oracle_env, oracle_env.unwrapped.oracle_action, limit=200)
    assert terminated and info["success"] and not truncated
    assert info["step"] <= 30, "6 m at up to 0.5 m a step, facing the goal"


def test_the_oracle_reaches_the_goal_from_the_fixed_start(oracle_env) -> None:
    # Validation point 3 at its favourable yaw: 32 steps in docs/simulator.md's table.
    oracle_env.reset(seed=0, options={"start": (14.0, -7.0, 135.0)})
    _, _, terminated, _, info = walk_until(oracle_env, oracle_env.unwrapped.oracle_action, limit=400)
    assert terminated and info["success"]
    assert 20 <= info["step"] <= 45, info["step"]
