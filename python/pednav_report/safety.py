"""Traffic tables: returns, gap closed, success and the safety counts of evaluations.

``python -m pednav_report.safety`` prints the markdown tables of the traffic results
folders (``docs/results/traffic-*``) from ``pednav-eval``'s per-episode
``results.csv``: per run, then per arm (mean ± sample standard deviation over its
runs, one run per seed). It replaces the per-folder scripts that each repeated this
arithmetic.

Per evaluation (one ``results.csv``):

- Avg.Int / Avg.Ext: the mean over points 0–7 / 8–13 of each point's mean discounted
  return (as ``pednav-eval``'s ``table.csv``; :data:`pednav_report.data.AVERAGES`);
- gap closed: ``(value − random) / (oracle − random)`` per average, against the
  references of ``--refs`` (a folder with ``random/results.csv`` and
  ``oracle/results.csv`` evaluated with the same traffic), computed from the arm's
  mean for an arm;
- success in % of episodes; vehicle hits, don't-walk entries and walker bumps per
  100 episodes; the mean kerb wait in seconds (``kerb_wait_steps`` × ``--dt``).

A ``results.csv`` written without traffic has no safety columns; its cells read "–".
This is descriptive bookkeeping for single runs and small arms, not a comparison: a
comparison of arms (≥ 5 seeds each) goes through ``python -m pednav_report``.
"""

from __future__ import annotations

import argparse
import csv
import math
import statistics
import sys
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

from .data import AVERAGES, DEFAULT_RESULTS, ReportError

#: The per-episode safety columns ``pednav-eval`` writes with traffic, and the
#: per-100-episodes name each gets in an :class:`Evaluation`.
SAFETY_COLUMNS = {"vehicle_hits": "hits", "dont_walk_entries": "dont_walk", "pedestrian_bumps": "bumps"}

#: Columns every ``results.csv`` must have.
REQUIRED = ("point", "discounted_return", "success")

#: The table's columns after the arm (and run) columns.
HEADER = (
    "Avg.Int | Avg.Ext | gap closed (Int / Ext) | success | hits / 100 | don't-walk entries / 100 | "
    "walker bumps / 100 | mean kerb wait"
)

#: Decision step in seconds (the paper's 0.25 s, `sim.dt`'s default).
DEFAULT_DT = 0.25


@dataclass(frozen=True)
class Evaluation:
    """One evaluation's summary; safety fields are None without traffic columns."""

    name: str
    avg_int: float
    avg_ext: float
    success: float  # % of episodes
    hits: float | None  # per 100 episodes
    dont_walk: float | None
    bumps: float | None
    kerb_wait_s: float | None
    episodes: int

    def value(self, key: str) -> float | None:
        return getattr(self, key)


#: The averaged fields, in table order.
FIELDS = ("avg_int", "avg_ext", "success", "hits", "dont_walk", "bumps", "kerb_wait_s")


def results_path(path: Path) -> Path:
    """A ``results.csv`` as given, or a run directory's (``eval/learned/results.csv``), or
    a folder holding one (a reference's)."""
    path = Path(path)
    if path.is_file():
        return path
    for candidate in (path / DEFAULT_RESULTS, path / "results.csv"):
        if candidate.is_file():
            return candidate
    raise ReportError(f"{path}: no results.csv there, nor {DEFAULT_RESULTS} under it")


def run_label(path: Path) -> str:
    """A run's label: the run directory's name, or a reference folder's."""
    p = Path(path)
    parts = p.parts
    if p.name == "results.csv" and len(parts) >= 4 and parts[-3] == "eval":
        return parts[-4]
    return p.parent.name if p.name == "results.csv" else p.name


def summarise(path: Path, dt: float = DEFAULT_DT, name: str | None = None) -> Evaluation:
    """Read one ``results.csv`` (see the module docs for what is computed)."""
    file = results_path(path)
    try:
        with file.open(newline="") as f:
            reader = csv.DictReader(f)
            columns = set(reader.fieldnames or ())
            missing = [c for c in REQUIRED if c not in columns]
            if missing:
                raise ReportError(f"{file}: not a results.csv of pednav-eval (missing columns {missing})")
            rows = list(reader)
    except OSError as e:
        raise ReportError(f"{file}: {e}") from e
    if not rows:
        raise ReportError(f"{file}: no episodes")
    by_point: dict[int, list[float]] = defaultdict(list)
    totals: dict[str, float] = defaultdict(float)
    successes = 0
    for line, row in enumerate(rows, start=2):
        try:
            by_point[int(row["point"])].append(float(row["discounted_return"]))
            successes += row["success"].strip().lower() == "true"
            for column in (*SAFETY_COLUMNS, "kerb_wait_steps"):
                if column in columns:
                    totals[column] += float(row[column])
        except (TypeError, ValueError, AttributeError) as e:
            raise ReportError(f"{file}: line {line}: cannot read {row}") from e
    means = {p: statistics.fmean(v) for p, v in by_point.items()}

    def average(points: tuple[int, ...]) -> float:
        values = [means[p] for p in points if p in means]
        return statistics.fmean(values) if values else math.nan

    n = len(rows)
    per100 = {key: (100 * totals[col] / n if col in columns else None) for col, key in SAFETY_COLUMNS.items()}
    return Evaluation(
        name=name or run_label(file),
        avg_int=average(AVERAGES["Int"]),
        avg_ext=average(AVERAGES["Ext"]),
        success=100 * successes / n,
        hits=per100["hits"],
        dont_walk=per100["dont_walk"],
        bumps=per100["bumps"],
        kerb_wait_s=totals["kerb_wait_steps"] / n * dt if "kerb_wait_steps" in columns else None,
        episodes=n,
    )


@dataclass(frozen=True)
class References:
    """The random walk's and the oracle's evaluations with the same traffic."""

    random: Evaluation
    oracle: Evaluation

    @staticmethod
    def load(folder: Path, dt: float = DEFAULT_DT) -> References:
        folder = Path(folder)
        return References(summarise(folder / "random", dt), summarise(folder / "oracle", dt))

    def gap(self, avg_int: float, avg_ext: float) -> str:
        def closed(value: float, key: str) -> float:
            lo, hi = self.random.value(key), self.oracle.value(key)
            return (value - lo) / (hi - lo)

        return f"{closed(avg_int, 'avg_int'):.2f} / {closed(avg_ext, 'avg_ext'):.2f}"


@dataclass
class SafetyArm:
    """An arm: a name, its evaluations (one per seed) and the references its gap uses."""

    name: str
    runs: list[Evaluation]
    refs: References


def cells(mean: dict[str, float | None], sd: dict[str, float | None] | None, refs: References) -> str:
    """The table's cells after the arm and run columns."""

    def cell(key: str, unit: str = "") -> str:
        m = mean[key]
        if m is None:
            return "–"
        s = sd[key] if sd else None
        return (f"{m:.1f} ± {s:.1f}" if s is not None else f"{m:.1f}") + unit

    return " | ".join(
        [
            cell("avg_int"),
            cell("avg_ext"),
            refs.gap(mean["avg_int"], mean["avg_ext"]),
            cell("success", " %"),
            cell("hits"),
            cell("dont_walk"),
            cell("bumps"),
            cell("kerb_wait_s", " s"),
        ]
    )


def arm_statistics(runs: list[Evaluation]) -> tuple[dict[str, float | None], dict[str, float | None] | None]:
    """Per field: the mean over the runs and, with ≥ 2 runs, the sample standard deviation."""
    mean: dict[str, float | None] = {}
    sd: dict[str, float | None] = {}
    for key in FIELDS:
        values = [r.value(key) for r in runs]
        if any(v is None for v in values):
            mean[key] = sd[key] = None
            continue
        mean[key] = statistics.fmean(values)
        sd[key] = statistics.stdev(values) if len(values) > 1 else None
    return mean, (sd if len(runs) > 1 else None)


def per_run_table(arms: list[SafetyArm], column: str) -> str:
    lines = [f"| {column} | run | {HEADER} |", "|---|---|" + "---|" * 8]
    for arm in arms:
        for run in arm.runs:
            mean = {k: run.value(k) for k in FIELDS}
            lines.append(f"| {arm.name} | {run.name} | {cells(mean, None, arm.refs)} |")
    return "\n".join(lines)


def per_arm_table(arms: list[SafetyArm], column: str) -> str:
    lines = [f"| {column} | runs | {HEADER} |", "|---|---|" + "---|" * 8]
    for arm in arms:
        mean, sd = arm_statistics(arm.runs)
        lines.append(f"| {arm.name} | {len(arm.runs)} | {cells(mean, sd, arm.refs)} |")
    return "\n".join(lines)


def per_point_table(evaluation_path: Path, dt: float = DEFAULT_DT) -> str:
    """Success, steps and safety counts per validation point of one ``results.csv``."""
    file = results_path(evaluation_path)
    try:
        with file.open(newline="") as f:
            rows = list(csv.DictReader(f))
        by_point: dict[int, list[dict[str, str]]] = defaultdict(list)
        for row in rows:
            by_point[int(row["point"])].append(row)
    except (OSError, KeyError, ValueError) as e:
        raise ReportError(f"{file}: cannot read it as a results.csv ({e})") from e
    if not rows:
        raise ReportError(f"{file}: no episodes")
    counts = [c for c in (*SAFETY_COLUMNS, "vehicle_bumps") if c in rows[0]]
    wait = "kerb_wait_steps" in rows[0]
    head = ["point", "episodes", "success", "mean steps", *(f"{c} / 100" for c in counts)]
    head += ["mean kerb wait"] if wait else []
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]

    def line(label: str, rs: list[dict[str, str]]) -> str:
        mean = lambda c: sum(float(r[c]) for r in rs) / len(rs)  # noqa: E731
        success = sum(r["success"].strip().lower() == "true" for r in rs) / len(rs)
        cols = [label, str(len(rs)), f"{100 * success:.1f} %", f"{mean('steps'):.0f}"]
        cols += [f"{100 * mean(c):.1f}" for c in counts]
        cols += [f"{mean('kerb_wait_steps') * dt:.1f} s"] if wait else []
        return "| " + " | ".join(cols) + " |"

    try:
        lines += [line(str(point), by_point[point]) for point in sorted(by_point)]
        lines.append(line("all", rows))
    except (KeyError, TypeError, ValueError, AttributeError) as e:
        raise ReportError(f"{file}: cannot read its rows ({e})") from e
    return "\n".join(lines)


def parse_safety_arm(spec: str, refs: References, dt: float) -> SafetyArm:
    """``NAME=PATH[,PATH…]``: each path a ``results.csv``, a run directory or a reference folder.
    The name may contain commas; the paths follow the first ``=``."""
    name, sep, paths = spec.partition("=")
    if not sep or not name.strip() or not paths.strip():
        raise ReportError(f"--arm `{spec}`: expected NAME=PATH[,PATH…]")
    return SafetyArm(name.strip(), [summarise(Path(p.strip()), dt) for p in paths.split(",") if p.strip()], refs)


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m pednav_report.safety",
        description="The traffic tables (returns, gap closed, success, vehicle hits, don't-walk entries, walker "
        "bumps, kerb wait) from pednav-eval's per-episode results.csv: per run, then per arm (mean ± sample "
        "standard deviation). Descriptive; a comparison of arms goes through `python -m pednav_report`.",
    )
    p.add_argument(
        "--arm",
        action="append",
        default=[],
        metavar="NAME=PATHS",
        help="an arm: comma-separated results.csv files, run directories (their eval/learned/results.csv) or "
        "reference folders; repeat for every arm, in table order",
    )
    p.add_argument(
        "--refs",
        type=Path,
        help="folder with random/results.csv and oracle/results.csv evaluated with the same traffic "
        "(e.g. docs/results/traffic-medium-references); required with --arm",
    )
    p.add_argument(
        "--refs-for",
        action="append",
        default=[],
        metavar="NAME=FOLDER",
        help="other references for the arm NAME (e.g. a run without traffic against the references without it)",
    )
    p.add_argument("--column", default="arm", help="heading of the arm column (default `arm`)")
    p.add_argument("--arms-only", action="store_true", help="print only the per-arm table")
    p.add_argument("--dt", type=float, default=DEFAULT_DT, help="seconds per decision step (0.25, sim.dt)")
    p.add_argument(
        "--per-point",
        type=Path,
        metavar="PATH",
        help="print the per-point table of one results.csv (or run directory) instead",
    )
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        if not args.dt > 0:
            raise ReportError(f"--dt {args.dt}: must be > 0 seconds")
        if args.per_point is not None:
            print(per_point_table(args.per_point, args.dt))
            return 0
        if not args.arm:
            raise ReportError("give at least one --arm NAME=PATHS (or --per-point PATH)")
        if args.refs is None:
            raise ReportError("--refs FOLDER is required with --arm (random/ and oracle/ evaluated with the traffic)")
        refs = References.load(args.refs, args.dt)
        other: dict[str, References] = {}
        for spec in args.refs_for:
            name, sep, folder = spec.partition("=")
            if not sep:
                raise ReportError(f"--refs-for `{spec}`: expected NAME=FOLDER")
            other[name.strip()] = References.load(Path(folder.strip()), args.dt)
        arms = []
        for spec in args.arm:
            arm = parse_safety_arm(spec, refs, args.dt)
            arm.refs = other.pop(arm.name, refs)
            arms.append(arm)
        if other:
            raise ReportError(f"--refs-for names no --arm: {sorted(other)}")
    except ReportError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if not args.arms_only:
        print(per_run_table(arms, args.column))
        print()
    print(per_arm_table(arms, args.column))
    return 0


if __name__ == "__main__":
    sys.exit(main())
