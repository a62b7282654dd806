"""Reading pednav's evaluation files and building normalised score matrices.

A run's per-episode file is the ``results.csv`` that ``pednav-eval`` writes
(``point,yaw_deg,run,discounted_return,success,steps``: one row per episode; the
columns are matched by name) and its per-point summary the ``table.csv`` beside it
(``point,episodes,mean,std,success_rate,oracle`` plus ``avg_int`` / ``avg_ext`` rows).
Both layouts come from ``shared/experiments/src/table.rs``.

The normalised score of an episode started at (point p, yaw y) is

    (G − random(p, y)) / (oracle(p, y) − random(p, y)),

0 at the random walk's return and 1 at the oracle's. A reference read from a
``results.csv`` gives a value per (point, yaw) — the mean of its episodes there; one
read from a ``table.csv`` has only a value per point (the ``mean`` column for the
random walk, the ``oracle`` column — the planner's return averaged over the 8 yaws —
for the oracle), used at every yaw of that point. Which one a report used is written
in it.

A *task* in rliable's sense is one start pose (point, yaw); a run's score on a task
is the mean normalised score of its episodes from that pose (10 in the protocol).
The linear normalisation commutes with that mean. Tasks are split as the repo's
Table III averages are: Int = points 0–7 (inside the curriculum region), Ext =
points 8–13.
"""

from __future__ import annotations

import csv
import math
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .common import AVERAGES, DEFAULT_RESULTS, ReportError, expand, run_name, split_named

#: Two ``table.csv`` oracle columns (written with 4 decimals) agree within this.
ORACLE_TOLERANCE = 5e-4

Pose = tuple[int, float]


def yaw_key(value: str | float) -> float:
    """The yaw as a dictionary key: degrees rounded to 1e-3, −0 as 0."""
    y = round(float(value), 3)
    return 0.0 if y == 0 else y


@dataclass
class RunResults:
    """One run's (one seed's) episodes, by start pose."""

    name: str
    path: Path
    returns: dict[Pose, np.ndarray]
    successes: dict[Pose, np.ndarray]
    #: The ``oracle`` column of the ``table.csv`` beside the file (point → value), if any:
    #: the planner's return on the run's own scene, so it fingerprints the scene.
    scene_oracle: dict[int, float] | None = None

    @property
    def points(self) -> list[int]:
        return sorted({p for p, _ in self.returns})

    def poses(self, points: tuple[int, ...]) -> list[Pose]:
        return sorted(k for k in self.returns if k[0] in points)

    def average_return(self, points: tuple[int, ...]) -> float:
        """Mean over ``points`` of the per-point mean return (Avg.Int / Avg.Ext as
        ``pednav-eval``'s ``table.csv`` and ``pednav-plot table`` compute them)."""
        means = []
        for p in points:
            g = [v for (q, _), r in self.returns.items() if q == p for v in r]
            if g:
                means.append(float(np.mean(g)))
        return float(np.mean(means)) if means else math.nan

    def success_rate(self) -> float:
        s = np.concatenate(list(self.successes.values()))
        return float(s.mean())

    @property
    def episodes(self) -> int:
        return int(sum(len(r) for r in self.returns.values()))


def read_results(path: Path, name: str | None = None) -> RunResults:
    """Read a ``results.csv`` of ``pednav-eval`` (and the ``table.csv`` beside it, if any)."""
    path = Path(path)
    returns: dict[Pose, list[float]] = defaultdict(list)
    successes: dict[Pose, list[bool]] = defaultdict(list)
    try:
        with path.open(newline="") as f:
            reader = csv.DictReader(f)
            need = {"point", "yaw_deg", "discounted_return"}
            if reader.fieldnames is None or not need <= set(reader.fieldnames):
                raise ReportError(f"{path}: not a results.csv of pednav-eval (needs columns {sorted(need)})")
            for n, row in enumerate(reader, start=2):
                try:
                    key = (int(row["point"]), yaw_key(row["yaw_deg"]))
                    returns[key].append(float(row["discounted_return"]))
                    successes[key].append(str(row.get("success", "")).strip().lower() == "true")
                except (TypeError, ValueError) as e:
                    raise ReportError(f"{path}: line {n}: cannot read {row}") from e
    except OSError as e:
        raise ReportError(f"{path}: {e}") from e
    if not returns:
        raise ReportError(f"{path}: no episodes")
    table = path.with_name("table.csv")
    scene_oracle = read_table(table)["oracle"] if table.is_file() else None
    return RunResults(
        name=name or run_name(path),
        path=path,
        returns={k: np.asarray(v, dtype=float) for k, v in returns.items()},
        successes={k: np.asarray(v, dtype=bool) for k, v in successes.items()},
        scene_oracle=scene_oracle or None,
    )


def read_table(path: Path) -> dict[str, dict[int, float]]:
    """The per-point rows of a ``table.csv``: ``{"mean": {point: v}, "oracle": {point: v}}``
    (``oracle`` empty where the column is blank)."""
    path = Path(path)
    out: dict[str, dict[int, float]] = {"mean": {}, "oracle": {}}
    try:
        with path.open(newline="") as f:
            reader = csv.DictReader(f)
            if reader.fieldnames is None or reader.fieldnames[:3] != ["point", "episodes", "mean"]:
                raise ReportError(
                    f"{path}: not the table.csv of a validation-point evaluation "
                    "(header point,episodes,mean,std,success_rate,oracle)"
                )
            for row in reader:
                if not row["point"].isdigit():  # avg_int / avg_ext rows
                    continue
                p = int(row["point"])
                out["mean"][p] = float(row["mean"])
                if row.get("oracle"):
                    out["oracle"][p] = float(row["oracle"])
    except OSError as e:
        raise ReportError(f"{path}: {e}") from e
    return out


@dataclass
class Reference:
    """The random walk's or the oracle's return per start pose (or per point)."""

    role: str  # "random" or "oracle"
    source: str
    #: "pose": a value per (point, yaw) from a results.csv; "point": per point, every yaw.
    resolution: str
    per_pose: dict[Pose, float] = field(default_factory=dict)
    per_point: dict[int, float] = field(default_factory=dict)
    episodes: int | None = None
    #: The ``oracle`` column of the table.csv this reference came with (its scene), if any.
    scene_oracle: dict[int, float] | None = None

    def value(self, pose: Pose) -> float:
        if self.resolution == "pose":
            if pose not in self.per_pose:
                raise ReportError(
                    f"{self.source}: the {self.role} reference has no episode at point {pose[0]}, yaw {pose[1]:g}"
                )
            return self.per_pose[pose]
        if pose[0] not in self.per_point:
            raise ReportError(f"{self.source}: the {self.role} reference has no value for point {pose[0]}")
        return self.per_point[pose[0]]

    def describe(self) -> str:
        if self.resolution == "pose":
            return f"`{self.source}` — per (point, yaw): the mean of its episodes there" + (
                f" ({self.episodes} episodes)" if self.episodes else ""
            )
        column = "`mean`" if self.role == "random" else "`oracle`"
        return f"`{self.source}` — per point only (the {column} column of a table.csv), used at every yaw of the point"


def load_reference(spec: str, role: str, runs: list[RunResults] | None = None) -> Reference:
    """A reference from ``spec``: a ``results.csv``, a ``table.csv``, a directory holding
    one (``results.csv`` preferred), or — for the oracle only — ``from-runs``: the
    ``oracle`` column of every run's ``table.csv`` (they must agree)."""
    if spec == "from-runs":
        if role != "oracle":
            raise ReportError("`from-runs` is a reference for --oracle only")
        return _oracle_from_runs(runs or [])
    path = Path(spec)
    if path.is_dir():
        if (path / "results.csv").is_file():
            path = path / "results.csv"
        elif (path / "table.csv").is_file():
            path = path / "table.csv"
        else:
            raise ReportError(f"{spec}: no results.csv or table.csv in this directory")
    if not path.is_file():
        raise ReportError(f"{spec}: no such file")
    with path.open(newline="") as f:
        header = f.readline().strip().split(",")
    if "discounted_return" in header:
        run = read_results(path, name=role)
        per_pose = {k: float(v.mean()) for k, v in run.returns.items()}
        per_point = {
            p: float(np.mean([v for (q, _), r in run.returns.items() if q == p for v in r])) for p in run.points
        }
        return Reference(role, str(spec), "pose", per_pose, per_point, run.episodes, run.scene_oracle)
    table = read_table(path)
    column = "mean" if role == "random" else "oracle"
    if not table[column]:
        raise ReportError(f"{path}: no `{column}` values for the {role} reference")
    return Reference(role, str(spec), "point", per_point=dict(table[column]), scene_oracle=table["oracle"] or None)


def _oracle_from_runs(runs: list[RunResults]) -> Reference:
    with_table = [r for r in runs if r.scene_oracle]
    if not with_table:
        raise ReportError("--oracle from-runs: no run has a table.csv with an oracle column beside its results.csv")
    first = with_table[0]
    for r in with_table[1:]:
        diff = _fingerprint_mismatch(first.scene_oracle or {}, r.scene_oracle or {})
        if diff:
            p, a, b = diff[0]
            raise ReportError(
                f"--oracle from-runs: the runs' oracle columns differ (different scenes?): point {p}: "
                f"{a:.4f} in {first.path.with_name('table.csv')}, {b:.4f} in {r.path.with_name('table.csv')}"
            )
    missing = [r.name for r in runs if not r.scene_oracle]
    if missing:
        raise ReportError(f"--oracle from-runs: no table.csv with an oracle column beside the results of {missing}")
    return Reference(
        "oracle",
        f"from-runs (the `oracle` column of the {len(runs)} runs' table.csv, identical in all)",
        "point",
        per_point=dict(first.scene_oracle or {}),
        scene_oracle=dict(first.scene_oracle or {}),
    )


def _fingerprint_mismatch(a: dict[int, float], b: dict[int, float]) -> list[tuple[int, float, float]]:
    return [(p, a[p], b[p]) for p in sorted(set(a) & set(b)) if abs(a[p] - b[p]) > ORACLE_TOLERANCE]


def scene_warnings(runs: list[RunResults], refs: list[Reference]) -> list[str]:
    """Where a reference's recorded oracle (its scene's) differs from the runs' —
    i.e. the reference was evaluated on another scene — or cannot be checked."""
    out = []
    run_fp = next((r.scene_oracle for r in runs if r.scene_oracle), None)
    for ref in refs:
        if ref.scene_oracle is None or run_fp is None:
            out.append(
                f"The {ref.role} reference ({ref.source}) could not be checked against the runs' scene "
                "(no oracle column on one side)."
            )
            continue
        diff = _fingerprint_mismatch(run_fp, ref.scene_oracle)
        if diff:
            pts = "; ".join(f"point {p}: {b:+.4f} there, {a:+.4f} in the runs' table.csv" for p, a, b in diff)
            out.append(
                f"The {ref.role} reference ({ref.source}) was evaluated on another scene than the runs: "
                f"its oracle column differs ({pts})."
            )
    return out


@dataclass
class Arm:
    """A variant: its runs (one per seed)."""

    name: str
    runs: list[RunResults]


def parse_arm(text: str, results: str = DEFAULT_RESULTS) -> Arm:
    """``NAME=SPEC`` (see :func:`expand`)."""
    name, spec = split_named(text, "--arm", "PATH[,PATH…] (paths may be globs)")
    paths = expand(spec, results)
    runs = [read_results(p) for p in paths]
    names = [r.name for r in runs]
    if len(set(names)) != len(names):  # fall back to the full path where names repeat
        for r in runs:
            r.name = str(r.path)
    return Arm(name, runs)


def task_poses(arms: list[Arm], points: tuple[int, ...]) -> list[Pose]:
    """The start poses of ``points`` that every run of every arm has (they must agree)."""
    sets = {(a.name, r.name): tuple(r.poses(points)) for a in arms for r in a.runs}
    distinct = set(sets.values())
    if len(distinct) != 1:
        first, *_ = sets.items()
        other = next(k for k, v in sets.items() if v != first[1])
        raise ReportError(
            f"runs cover different start poses on points {points[0]}–{points[-1]}: "
            f"{first[0]} has {len(first[1])}, {other} has {len(sets[other])}"
        )
    return list(distinct.pop())


def normalised(returns: np.ndarray, random: float, oracle: float, where: str = "") -> np.ndarray:
    """(G − random) / (oracle − random)."""
    if not oracle > random:
        raise ReportError(f"oracle {oracle} is not above the random walk {random}{where}")
    return (np.asarray(returns, dtype=float) - random) / (oracle - random)


def score_matrix(runs: list[RunResults], poses: list[Pose], random: Reference, oracle: Reference) -> np.ndarray:
    """(runs × tasks): each run's mean normalised score over its episodes at each pose."""
    m = np.empty((len(runs), len(poses)))
    for j, pose in enumerate(poses):
        r, o = random.value(pose), oracle.value(pose)
        where = f" at point {pose[0]}, yaw {pose[1]:g}"
        for i, run in enumerate(runs):
            m[i, j] = normalised(run.returns[pose], r, o, where).mean()
    return m
