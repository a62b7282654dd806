"""The single environment against Gymnasium's checker and the simulator's known facts.

Facts of the reference corner used here (shared/sim/scenes/corner.toml, docs/simulator.md):
the first task is (12, 7) facing east, 8 m west of the goal centre (20, 7); the goal
area is x ∈ [18, 22], y ∈ [5, 9]; the goal-side sidewalk pays −0.6 a step, the goal
+15, full speed 0.125 · 2 m/s; the world is x ∈ [−30, 50], y ∈ [−35, 35].
"""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env, data_equivalence
from support import gymnasium_warnings, make, rollout, walk_until

import pednav_gym
from pednav_gym import PednavError

FULL_SPEED_AHEAD = np.array([1.0, 0.0, 0.0], dtype=np.float32)


@pytest.mark.parametrize("obs_mode", ["state", "pixels"])
def test_gymnasiums_env_checker_passes_without_a_warning(obs_mode: str) -> None:
    env = make(obs_mode=obs_mode, image_size=84, t_max=2000)
    with gymnasium_warnings() as warned:
        check_env(env.unwrapped)
    assert warned == []
    env.close()


def test_observations_are_uint8_frames_or_the_22_float_state() -> None:
    pixels = make(image_size=42)
    obs, _ = pixels.reset(seed=0)
    assert obs.shape == (42, 42, 1) and obs.dtype == np.uint8
    assert obs.std() > 0, "a frame of the crossing is not one flat grey"
    pixels.close()
    state = make(obs_mode="state")
    obs, _ = state.reset(seed=0)
    assert obs.shape == (pednav_gym._pednav.STATE_DIM,) == (22,) and obs.dtype == np.float32
    # The goal centre lies 8 m straight ahead of the first task: 8 / 20 m, 0.
    np.testing.assert_allclose(obs[:2], [0.4, 0.0], atol=1e-5)
    state.close()


def test_the_action_space_is_the_rust_envs() -> None:
    env = make(obs_mode="state")
    assert env.action_space.shape == (3,) and env.action_space.dtype == np.float32
    np.testing.assert_array_equal(env.action_space.low, [-1.0, -1.0, -1.0])
    np.testing.assert_array_equal(env.action_space.high, [1.0, 1.0, 1.0])
    env.close()


@pytest.mark.parametrize("start", [(14.0, -7.0, 135.0), (12.0, 7.0, 0.0), (5.5, 7.0, -90.0), (-7.0, -7.0, 180.0)])
def test_a_start_given_in_the_reset_options_is_where_the_episode_starts(start: tuple[float, float, float]) -> None:
    env = make(obs_mode="state")
    _, info = env.reset(seed=0, options={"start": start})
    np.testing.assert_allclose(info["pose"], start, atol=1e-4)
    assert info["step"] == 0 and not info["success"] and not info["collided"]
    assert info["reward_map"] == info["reward_speed"] == info["reward_collision"] == 0.0
    env.close()


@pytest.mark.parametrize(("start", "why"), [((1000.0, 0.0, 0.0), "outside the world"), ((20.0, 7.0, 0.0), "goal")])
def test_a_start_the_scene_refuses_raises_the_rust_error(start: tuple[float, float, float], why: str) -> None:
    env = make(obs_mode="state")
    with pytest.raises(PednavError, match="invalid task pose") as error:
        env.reset(options={"start": start})
    assert why in str(error.value)
    env.close()


def test_unknown_reset_options_are_refused() -> None:
    env = make(obs_mode="state")
    with pytest.raises(ValueError, match="strat"):
        env.reset(options={"strat": (12.0, 7.0, 0.0)})
    env.close()


def test_info_carries_the_rewards_parts_which_sum_to_the_reward() -> None:
    env = make(obs_mode="state", start="validation", t_max=50)
    steps = [out for out in rollout(env, seed=3, steps=200) if len(out) == 5]
    for _, reward, terminated, _, info in steps:
        parts = np.float32(info["reward_map"]) + np.float32(info["reward_speed"])
        assert parts + np.float32(info["reward_collision"]) == np.float32(reward)
        assert info["success"] == terminated
    env.close()


def test_traffic_is_a_keyword_and_its_safety_events_are_in_info() -> None:
    env = make(obs_mode="state", start="validation", t_max=800, traffic="heavy", traffic_non_yielding=1.0)
    check_env(env.unwrapped, skip_render_check=True)
    obs, info = env.reset(seed=4, options={"start": (0.0, -2.5, 90.0)})  # standing in a lane of the crossing box
    assert {"vehicle_hit", "dont_walk_entry", "pedestrian_bump", "kerb_wait", "reward_traffic"} <= set(info)
    # The state preset knows the traffic: 28 entries after the scene's 22 (pednav_sim::state_obs).
    assert obs.shape == (pednav_gym._pednav.STATE_DIM + pednav_gym._pednav.TRAFFIC_STATE_DIM,) == (50,)
    assert obs[30] == 1.0, "heavy traffic has a vehicle within 40 m of the crossing's centre"
    assert sum(obs[26:28]) <= 1.0, "WALK and the clearance never show at once"
    for _ in range(800):
        _, reward, terminated, truncated, info = env.step(np.array([-1.0, 0.0, 0.0], dtype=np.float32))
        parts = np.float32(info["reward_map"]) + np.float32(info["reward_speed"])
        assert (parts + np.float32(info["reward_collision"])) + np.float32(info["reward_traffic"]) == np.float32(reward)
        if terminated or truncated:
            break
    assert terminated and info["vehicle_hit"] and not info["success"], "no vehicle reached an agent standing in its lane"
    assert info["reward_traffic"] == -300.0
    env.close()


def test_ground_signals_are_a_keyword_and_change_only_the_frames() -> None:
    frames = []
    for ground_signals in ("off", "edges"):
        env = make(image_size=42, traffic="light", traffic_ground_signals=ground_signals)
        # Facing along the east zebra 0.6 m short of its south kerb, where its edge lines begin.
        obs, info = env.reset(seed=7, options={"start": (13.0, -5.6, 90.0)})
        frames.append((obs, info["pose"]))
        env.close()
    (off, pose_off), (edges, pose_edges) = frames
    assert np.array_equal(pose_off, pose_edges)
    assert (off != edges).sum() >= 20, "the edge lines are not in the frame"


def test_a_step_on_the_goal_side_sidewalk_pays_its_region_and_the_speed() -> None:
    env = make(obs_mode="state", start="first_task")
    env.reset(seed=0)
    _, reward, terminated, truncated, info = env.step(FULL_SPEED_AHEAD)
    assert not terminated and not truncated and not info["collided"]
    assert info["region"] == "goal-side sidewalk"
    assert info["reward_map"] == pytest.approx(-0.6) and info["reward_speed"] == pytest.approx(0.25)
    assert reward == pytest.approx(-0.35)
    np.testing.assert_allclose(info["pose"], [12.5, 7.0, 0.0], atol=1e-4)
    env.close()


def test_walking_into_a_building_collides_and_costs_the_collision_reward() -> None:
    # The south-east block starts at y = −9 for x in [9, 20] (as the Rust test walks it).
    env = make(obs_mode="state", start=(15.0, -7.0, -90.0))
    env.reset(seed=0)
    outs = [env.step(FULL_SPEED_AHEAD) for _ in range(20)]
    hits = [info for *_, info in outs if info["collided"]]
    assert len(hits) >= 15, "pressing against a wall collides every step"
    for info in hits:
        assert info["reward_collision"] == pytest.approx(-3.0) and info["region"] == "sidewalk"
    assert outs[-1][4]["pose"][1] > -9.0 + 0.29, "stopped at the wall"
    env.close()


def test_reaching_the_goal_terminates_with_success_and_the_goal_reward() -> None:
    env = make(obs_mode="state", start="first_task")
    env.reset(seed=0)
    _, reward, terminated, truncated, info = walk_until(env, lambda: FULL_SPEED_AHEAD, limit=40)
    assert terminated and not truncated and info["success"]
    assert info["region"] == "goal" and info["reward_map"] == pytest.approx(15.0)
    assert reward == pytest.approx(15.25)
    env.close()


def test_t_max_truncates_and_a_finished_episode_must_be_reset() -> None:
    env = make(obs_mode="state", t_max=5)
    env.reset(seed=0)
    standing = np.array([-1.0, 0.0, 0.0], dtype=np.float32)
    outs = [env.step(standing) for _ in range(5)]
    assert [out[3] for out in outs] == [False] * 4 + [True]
    assert not any(out[2] for out in outs)
    with pytest.raises(PednavError, match="must be reset"):
        env.step(standing)
    env.close()


def test_a_non_finite_action_is_refused_naming_the_environment() -> None:
    env = make(obs_mode="state")
    env.reset(seed=0)
    with pytest.raises(PednavError, match="not finite"):
        env.step(np.array([np.nan, 0.0, 0.0], dtype=np.float32))
    env.close()


def test_the_same_seed_gives_the_same_trajectory_and_another_seed_another() -> None:
    kwargs = {"obs_mode": "state", "start": "validation", "t_max": 30}
    first, second, other = make(**kwargs), make(**kwargs), make(**kwargs)
    a, b = rollout(first, seed=11, steps=120), rollout(second, seed=11, steps=120)
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        assert data_equivalence(x, y, exact=True)
    c = rollout(other, seed=12, steps=120)
    starts = lambda record: [out[1]["pose"].tolist() for out in record if len(out) == 2]  # noqa: E731
    assert starts(a) != starts(c)
    for env in (first, second, other):
        env.close()


def test_pixels_are_deterministic_with_domain_randomisation_and_the_seed_changes_the_look() -> None:
    kwargs = {"image_size": 42, "domain_randomization": True}
    first, second, other = make(**kwargs), make(**kwargs), make(**kwargs)
    a, b = rollout(first, seed=5, steps=10), rollout(second, seed=5, steps=10)
    for x, y in zip(a, b, strict=True):
        assert data_equivalence(x, y, exact=True)
    c = rollout(other, seed=6, steps=10)
    assert not np.array_equal(a[0][0], c[0][0]), "another episode seed draws another look"
    for env in (first, second, other):
        env.close()


def test_a_constructor_seed_makes_the_first_unseeded_reset_reproducible() -> None:
    first = make(obs_mode="state", start="validation", seed=4)
    second = make(obs_mode="state", start="validation", seed=4)
    assert data_equivalence(first.reset(), second.reset(), exact=True)
    first.close()
    second.close()


@pytest.mark.parametrize(
    "action",
    [np.zeros(2, np.float32), np.zeros((3, 2), np.float32), np.array(["fast", "left", "ahead"]), [0.0, 0.0, 0.0, 0.0]],
    ids=["too-short", "wrong-shape", "strings", "too-long-list"],
)
def test_a_malformed_action_raises_and_the_episode_goes_on(action: object) -> None:
    env = make(obs_mode="state")
    env.reset(seed=0)
    with pytest.raises(ValueError):
        env.step(action)
    _, _, terminated, truncated, info = env.step(np.zeros(3, np.float32))
    assert info["step"] == 1, "the refused action took no step"
    env.close()
