"""The vector environment against Gymnasium's own: ``SyncVectorEnv`` over single
environments is the reference (Gymnasium ships no checker for vector environments), and
Gymnasium's vector wrappers must run on it unchanged."""

from __future__ import annotations

import threading
import time

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from gymnasium.vector.utils import batch_space
from gymnasium.wrappers.vector import RecordEpisodeStatistics

import pednav_gym
from pednav_gym import CornerVectorEnv, PednavError

STATE = {"obs_mode": "state", "start": "validation", "t_max": 7}


def make_vec(num_envs: int, mode: str, **kwargs: object) -> gym.vector.VectorEnv:
    return gym.make_vec(pednav_gym.ENV_ID, num_envs=num_envs, vectorization_mode=mode, **kwargs)


def random_actions(seed: int, num_envs: int, steps: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.uniform(-1.0, 1.0, size=(num_envs, 3)).astype(np.float32) for _ in range(steps)]


def test_make_vec_builds_the_batched_env_with_batched_spaces() -> None:
    envs = make_vec(3, "vector_entry_point", **STATE)
    assert isinstance(envs.unwrapped, CornerVectorEnv) and envs.num_envs == 3
    assert envs.observation_space == batch_space(envs.single_observation_space, 3)
    assert envs.action_space == batch_space(envs.single_action_space, 3)
    assert envs.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    envs.close()


def test_the_vector_env_matches_gymnasiums_sync_vector_env_step_for_step() -> None:
    ours, reference = make_vec(4, "vector_entry_point", **STATE), make_vec(4, "sync", **STATE)
    assert isinstance(reference, SyncVectorEnv)
    assert data_equivalence(ours.reset(seed=3), reference.reset(seed=3), exact=True)
    ended = 0
    for actions in random_actions(0, 4, 40):
        a, b = ours.step(actions), reference.step(actions)
        for name, x, y in zip(("obs", "rewards", "terminated", "truncated", "infos"), a, b, strict=True):
            assert data_equivalence(x, y, exact=True), name
        ended += int(np.sum(a[2] | a[3]))
    assert ended >= 8, "t_max = 7 ends every episode, so autoresets were exercised"
    ours.close()
    reference.close()


def test_partial_resets_and_per_environment_starts_match_the_reference() -> None:
    ours, reference = make_vec(3, "vector_entry_point", **STATE), make_vec(3, "sync", **STATE)
    ours.reset(seed=8)
    reference.reset(seed=8)
    mask = np.array([True, False, True])
    options = {"reset_mask": mask, "start": (14.0, -7.0, 180.0)}
    seeds = [20, None, 22]
    # `SyncVectorEnv.reset` pops "reset_mask" from the options it is given: each gets a copy.
    a = ours.reset(seed=seeds, options=dict(options))
    b = reference.reset(seed=seeds, options=dict(options))
    assert data_equivalence(a, b, exact=True)
    np.testing.assert_allclose(a[1]["pose"][mask][:, :2], [[14.0, -7.0]] * 2, atol=1e-4)
    assert list(a[1]["_pose"]) == [True, False, True]
    obs, infos = ours.reset(options={"starts": [None, (12.0, 7.0, 0.0), None]})
    np.testing.assert_allclose(infos["pose"][1], [12.0, 7.0, 0.0], atol=1e-4)
    ours.close()
    reference.close()


@pytest.mark.parametrize("num_envs", [1, 3])
def test_pixel_observations_are_each_environments_own_view(num_envs: int) -> None:
    # The batch renders all views in one atlas, the reference one view per renderer:
    # the same cameras, through viewports at other offsets, so frames may differ by
    # rounding at edges — but a frame of another pose would differ everywhere.
    pixels = {"image_size": 42, "start": "validation", "t_max": 7}
    ours, reference = make_vec(num_envs, "vector_entry_point", **pixels), make_vec(num_envs, "sync", **pixels)
    a, b = ours.reset(seed=1), reference.reset(seed=1)
    assert a[0].shape == (num_envs, 42, 42, 1) and a[0].dtype == np.uint8
    for actions in random_actions(2, num_envs, 3):
        a, b = ours.step(actions), reference.step(actions)
        assert data_equivalence(a[1:], b[1:], exact=True)
        difference = np.abs(a[0].astype(np.int16) - b[0].astype(np.int16)).reshape(num_envs, -1).mean(axis=1)
        assert np.all(difference < 0.5), difference
    ours.close()
    reference.close()


def test_an_environment_that_restarts_ignores_its_action() -> None:
    envs = make_vec(2, "vector_entry_point", obs_mode="state", t_max=2)
    envs.reset(seed=0)
    still = np.zeros((2, 3), dtype=np.float32)
    envs.step(still)
    _, _, _, truncated, _ = envs.step(still)
    assert truncated.all()
    nan_for_restarting = np.full((2, 3), np.nan, dtype=np.float32)
    _, rewards, terminated, truncated, infos = envs.step(nan_for_restarting)
    assert not terminated.any() and not truncated.any()
    np.testing.assert_array_equal(rewards, [0.0, 0.0])
    np.testing.assert_array_equal(infos["step"], [0, 0])
    with pytest.raises(PednavError, match="not finite"):
        envs.step(nan_for_restarting)
    envs.close()


def test_with_autoreset_disabled_ended_environments_wait_for_a_masked_reset() -> None:
    envs = make_vec(2, "vector_entry_point", obs_mode="state", t_max=2, autoreset_mode=AutoresetMode.DISABLED)
    assert envs.metadata["autoreset_mode"] is AutoresetMode.DISABLED
    envs.reset(seed=0)
    action = np.zeros((2, 3), dtype=np.float32)
    envs.step(action)
    envs.step(action)
    with pytest.raises(PednavError, match="must be reset"):
        envs.step(action)
    _, infos = envs.reset(options={"reset_mask": np.array([True, True])})
    np.testing.assert_array_equal(infos["step"], [0, 0])
    _, _, _, _, infos = envs.step(action)
    np.testing.assert_array_equal(infos["step"], [1, 1])
    envs.close()


def test_gymnasiums_episode_statistics_wrapper_counts_the_same_episodes() -> None:
    ours = RecordEpisodeStatistics(make_vec(3, "vector_entry_point", **STATE))
    reference = RecordEpisodeStatistics(make_vec(3, "sync", **STATE))
    ours.reset(seed=5)
    reference.reset(seed=5)
    for actions in random_actions(4, 3, 30):
        ours.step(actions)
        reference.step(actions)
    assert len(ours.return_queue) >= 9
    assert list(ours.return_queue) == list(reference.return_queue)
    assert list(ours.length_queue) == list(reference.length_queue)
    ours.close()
    reference.close()


def test_render_gives_each_environments_view_for_people() -> None:
    envs = make_vec(2, "vector_entry_point", obs_mode="state", render_mode="rgb_array", render_size=128)
    envs.reset(options={"starts": [(12.0, 7.0, 0.0), (14.0, -7.0, 180.0)]})
    views = envs.render()
    assert len(views) == 2
    for view in views:
        assert view.shape == (128, 128, 3) and view.dtype == np.uint8
    assert not np.array_equal(views[0], views[1]), "two poses, two views"
    envs.close()


def test_the_gil_is_released_while_rust_works() -> None:
    # The oracle plans for seconds inside one call; a Python thread must keep running.
    envs = make_vec(2, "vector_entry_point", obs_mode="state")
    envs.reset(seed=0)
    ticks: list[float] = []
    stop = threading.Event()

    def tick() -> None:
        while not stop.is_set():
            ticks.append(time.monotonic())
            time.sleep(0.001)

    ticker = threading.Thread(target=tick)
    ticker.start()
    began = time.monotonic()
    actions = envs.unwrapped.oracle_actions()
    ended = time.monotonic()
    stop.set()
    ticker.join()
    inside = [began] + [t for t in ticks if began <= t <= ended] + [ended]
    longest_pause = max(b - a for a, b in zip(inside, inside[1:]))
    assert longest_pause < (ended - began) / 2, f"the thread paused {longest_pause:.3f} s of {ended - began:.3f} s"
    assert actions.shape == (2, 3) and actions.dtype == np.float32
    envs.close()


def test_a_batch_of_actions_of_the_wrong_shape_raises_and_nothing_steps() -> None:
    envs = make_vec(3, "vector_entry_point", **STATE)
    envs.reset(seed=0)
    for bad in (np.zeros((2, 3), np.float32), np.zeros(9, np.float32)[:8], np.full((3, 3), np.nan, np.float32)):
        with pytest.raises(ValueError):
            envs.step(bad)
    _, _, _, _, infos = envs.step(np.zeros((3, 3), np.float32))
    assert list(infos["step"]) == [1, 1, 1], "the refused batches took no step"
    envs.close()
