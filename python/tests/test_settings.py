"""Settings, scenes and backends given as keyword arguments: read and checked by the Rust
config code (``SimConfig``'s schema and ``SimConfig::validate``, the scene loader), with
errors that name the field."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support import make

from pednav_gym import PednavError


@pytest.mark.parametrize(
    ("settings", "named"),
    [
        ({"max_speed": 50.0}, "max_speed"),  # out of (0, 20] m/s
        ({"image_size": 4}, "image_size"),  # out of [8, 1024]
        ({"t_max": 0}, "t_max"),  # at least 1
        ({"fov_deg": 179.0}, "fov_deg"),
        ({"t_max": "long"}, "t_max"),  # not an integer
        ({"image_size": 84.5}, "image_size"),
        ({"t_max": -3}, "t_max"),
        ({"obs_mode": "depth"}, "obs_mode"),  # not a mode
        ({"maxspeed": 1.0}, "maxspeed"),  # not a field
        ({"max_speed": [1.0]}, "max_speed"),  # not a bool, number or string
        ({"traffic": "medium", "traffic_ground_signals": "sideways"}, "traffic_ground_signals"),  # not a kind
        ({"traffic_ground_signals": "edges"}, "traffic_ground_signals"),  # needs traffic
    ],
)
def test_a_refused_setting_raises_naming_the_field(settings: dict[str, object], named: str) -> None:
    with pytest.raises(PednavError, match=named):
        make(**settings)


def test_the_error_is_a_value_error() -> None:
    assert issubclass(PednavError, ValueError)
    with pytest.raises(ValueError):
        make(dt=-1.0)


def test_a_missing_scene_file_raises_naming_the_file(tmp_path: Path) -> None:
    missing = tmp_path / "nowhere.toml"
    with pytest.raises(PednavError, match="nowhere.toml"):
        make(scene=missing)


def test_an_invalid_scene_file_raises_naming_the_field(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "bad"\nextent = [0.0, 0.0, 10.0]\n')
    with pytest.raises(PednavError, match="bad.toml"):
        make(scene=bad)


def test_an_unknown_built_in_scene_lists_the_built_in_ones() -> None:
    with pytest.raises(PednavError, match="built-in:corner_plain"):
        make(scene="built-in:nowhere")


def test_an_unknown_backend_is_refused_naming_it() -> None:
    with pytest.raises(PednavError, match="metal"):
        make(backend="metal")


def test_settings_reach_the_simulator() -> None:
    env = make(obs_mode="state", max_speed=1.0, dt=0.5, t_max=np.int64(7), scene="built-in:corner_plain")
    settings = env.unwrapped.settings
    assert settings["max_speed"] == 1.0 and settings["dt"] == 0.5 and settings["t_max"] == 7
    assert settings["obs_mode"] == "state" and settings["image_size"] == 84  # the Rust default
    assert env.metadata["render_fps"] == 2.0
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([1.0, 0.0, 0.0], dtype=np.float32))
    # Full speed is now 1 m/s: r_v = 0.125 · 1, and 0.5 s walks 0.5 m.
    assert info["reward_speed"] == pytest.approx(0.125)
    np.testing.assert_allclose(info["pose"][:2], [12.5, 7.0], atol=1e-4)
    env.close()


def test_the_former_name_of_the_state_mode_still_reads() -> None:
    env = make(obs_mode="state_debug")
    assert env.unwrapped.settings["obs_mode"] == "state"
    assert env.observation_space.shape == (22,)
    env.close()
