"""Types of the extension module built from python/src (Rust, pyo3). See python/src/lib.rs."""

from collections.abc import Sequence
from typing import Any

ACTION_DIM: int
ACTION_LOW: float
ACTION_HIGH: float
STATE_DIM: int

class PednavError(ValueError):
    """A request the simulator refused; the message is pednav-sim's and names the field."""

StartRequest = tuple[int, float, float, float, int]
"""(environment, x m, y m, yaw °, episode seed)."""

class StepBatch:
    """Per-environment results of one reset or step; every list has one entry per environment."""

    reward: list[float]
    reward_map: list[float]
    reward_speed: list[float]
    reward_collision: list[float]
    terminated: list[bool]
    truncated: list[bool]
    collided: list[bool]
    reward_traffic: list[float]
    vehicle_hit: list[bool]
    dont_walk_entry: list[bool]
    pedestrian_bump: list[bool]
    kerb_wait: list[bool]
    x: list[float]
    y: list[float]
    yaw_deg: list[float]
    head_yaw_deg: list[float]
    step: list[int]
    region: list[str]
    def __len__(self) -> int: ...

class Simulator:
    """M pedestrian environments of pednav-sim sharing one world and one renderer."""

    def __init__(
        self,
        num_envs: int,
        scene: str | None = None,
        settings: dict[str, Any] | None = None,
        backend: str | None = None,
    ) -> None: ...
    @property
    def num_envs(self) -> int: ...
    @property
    def settings(self) -> dict[str, Any]: ...
    @property
    def scene(self) -> str: ...
    @property
    def adapter(self) -> str | None: ...
    def state_bounds(self) -> tuple[list[float], list[float]]: ...
    def validation_starts(self) -> list[tuple[int, float, float, float]]: ...
    def first_task(self) -> tuple[float, float, float]: ...
    def fixed_start(self) -> tuple[float, float, float]: ...
    def reset(self, starts: Sequence[StartRequest]) -> tuple[bytearray, StepBatch]: ...
    def step(
        self, actions: Sequence[Sequence[float]], restarts: Sequence[StartRequest] = ...
    ) -> tuple[bytearray, StepBatch]: ...
    def observations(self) -> bytearray: ...
    def render_people(self, envs: Sequence[int], size: int = 512) -> bytearray: ...
    def oracle_actions(self) -> list[list[float]]: ...

def validation_starts(scene: str | None = None) -> list[tuple[int, float, float, float]]: ...
