"""Traffic tables: returns, gap closed, success and the safety counts of evaluations.

``python -m pednav_report.traffic`` prints the markdown tables of the traffic results
folders (``docs/results/traffic-*``) from ``pednav-eval``'s per-episode
``results.csv``, with the standard library alone.

Per evaluation (one ``results.csv``; :class:`Evaluation`):

- Avg.Int / Avg.Ext: the mean over points 0–7 / 8–13 of each point's mean discounted
  return (as ``pednav-eval``'s ``table.csv``); every one of the 14 points must be there;
- success in % of episodes; vehicle hits, don't-walk entries and walker bumps per
  100 episodes; the mean kerb wait in seconds (``kerb_wait_steps`` × ``--dt``).

Per arm (one evaluation per seed): the mean of each figure and, with two runs or
more, the sample standard deviation (``mean ± sd``). Gap closed is
``(value − random) / (oracle − random)`` per average against the references of
``--refs`` — a folder with ``random/`` and ``oracle/`` evaluated with the same traffic —
computed from the arm's mean. A ``results.csv`` written without traffic has no safety
columns and its cells read "–"; an arm that mixes the two is refused.

``--per-point RUN`` prints one evaluation per validation point instead: episodes,
success, mean steps, each safety column present per 100 episodes (vehicle bumps
included, under the CSV's own column names) and the kerb wait, then the row ``all``.

This is bookkeeping for single runs and small arms: it draws no interval and calls no
arm ahead. A comparison of arms (≥ 5 seeds each) goes through ``python -m pednav_report``.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
from collections import defaultdict
from dataclasses import dataclass, fields
from pathlib import Path

from .common import AVERAGES, ReportError, expand, run_name, split_named

#: The per-episode safety columns ``pednav-eval`` writes with traffic → the
#: per-100-episodes field of an :class:`Evaluation`.
SAFETY_COLUMNS = {"vehicle_hits": "hits", "dont_walk_entries": "dont_walk", "pedestrian_bumps": "bumps"}

#: Columns every ``results.csv`` must have.
REQUIRED = ("point", "discounted_return", "success", "steps")

#: The table's columns after the arm (and run) columns.
HEADER = (
    "Avg.Int | Avg.Ext | gap closed (Int / Ext) | success | hits / 100 | don't-walk entries / 100 | "
    "walker bumps / 100 | mean kerb wait"
)

#: Decision step in seconds (the paper's 0.25 s, `sim.dt`'s default).
DEFAULT_DT = 0.25


@dataclass(frozen=True)
class Evaluation:
    """One evaluation's figures; the safety fields are None without traffic columns."""

    name: str
    avg_int: float
    avg_ext: float
    success: float  # % of episodes
    hits: float | None  # per 100 episodes
    dont_walk: float | None
    bumps: float | None
    kerb_wait_s: float | None


#: The averaged fields, in table order.
FIELDS = tuple(f.name for f in fields(Evaluation) if f.name != "name")


def read_rows(path: Path) -> tuple[Path, list[dict[str, str]]]:
    """The rows of a ``results.csv`` (given as the file, a run directory or a folder
    holding one), with its required columns checked."""
    file = expand(str(path))[0]
    try:
        with file.open(newline="") as f:
            reader = csv.DictReader(f)
            missing = [c for c in REQUIRED if c not in (reader.fieldnames or ())]
            if missing:
                raise ReportError(f"{file}: not a results.csv of pednav-eval (missing columns {missing})")
            rows = list(reader)
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise ReportError(f"{file}: {e}") from e
    if not rows:
        raise ReportError(f"{file}: no episodes")
    return file, rows


def is_success(row: dict[str, str]) -> bool:
    return row["success"].strip().lower() == "true"


def summarise(path: Path, dt: float = DEFAULT_DT) -> Evaluation:
    """One evaluation's figures (the module docs say which)."""
    file, rows = read_rows(path)
    columns = rows[0].keys()
    by_point: dict[int, list[float]] = defaultdict(list)
    totals: dict[str, float] = defaultdict(float)
    for line, row in enumerate(rows, start=2):
        try:
            by_point[int(row["point"])].append(float(row["discounted_return"]))
            for column in (*SAFETY_COLUMNS, "kerb_wait_steps"):
                if column in columns:
                    totals[column] += float(row[column])
        except (TypeError, ValueError) as e:
            raise ReportError(f"{file}: line {line}: cannot read {row}") from e
    missing = [p for points in AVERAGES.values() for p in points if p not in by_point]
    if missing:
        raise ReportError(f"{file}: no episodes from validation points {missing} (Avg.Int / Avg.Ext need 0–13)")
    means = {p: statistics.fmean(v) for p, v in by_point.items()}
    n = len(rows)
    per100 = {key: (100 * totals[col] / n if col in columns else None) for col, key in SAFETY_COLUMNS.items()}
    return Evaluation(
        name=run_name(file),
        avg_int=statistics.fmean(means[p] for p in AVERAGES["Int"]),
        avg_ext=statistics.fmean(means[p] for p in AVERAGES["Ext"]),
        success=100 * sum(map(is_success, rows)) / n,
        kerb_wait_s=totals["kerb_wait_steps"] / n * dt if "kerb_wait_steps" in columns else None,
        **per100,
    )


@dataclass(frozen=True)
class References:
    """The random walk's and the oracle's evaluations with the same traffic."""

    folder: Path
    random: Evaluation
    oracle: Evaluation

    @staticmethod
    def load(folder: Path, dt: float = DEFAULT_DT) -> References:
        folder = Path(folder)
        refs = References(folder, summarise(folder / "random", dt), summarise(folder / "oracle", dt))
        for key in ("avg_int", "avg_ext"):
            if getattr(refs.oracle, key) == getattr(refs.random, key):
                raise ReportError(f"{folder}: the random walk and the oracle have the same {key}: no gap to close")
        return refs

    def gap(self, avg_int: float, avg_ext: float) -> str:
        def closed(value: float, key: str) -> float:
            lo, hi = getattr(self.random, key), getattr(self.oracle, key)
            return (value - lo) / (hi - lo)

        return f"{closed(avg_int, 'avg_int'):.2f} / {closed(avg_ext, 'avg_ext'):.2f}"


@dataclass(frozen=True)
class TrafficArm:
    """An arm: a name, its evaluations (one per seed) and the references of its gap."""

    name: str
    runs: list[Evaluation]
    refs: References

    def statistics(self) -> tuple[dict[str, float | None], dict[str, float | None] | None]:
        """Per field: the mean over the runs and, with ≥ 2 runs, the sample standard deviation."""
        mean: dict[str, float | None] = {}
        sd: dict[str, float | None] = {}
        for key in FIELDS:
            values = [getattr(r, key) for r in self.runs]
            if None in values:
                mean[key] = sd[key] = None
                continue
            mean[key] = statistics.fmean(values)
            sd[key] = statistics.stdev(values) if len(values) > 1 else None
        return mean, (sd if len(self.runs) > 1 else None)


def read_arm(spec: str, refs: References, dt: float) -> TrafficArm:
    """``NAME=PATH[,PATH…]``: each path a ``results.csv``, a run directory, a folder
    holding one, or a glob (:func:`pednav_report.common.expand`)."""
    name, paths = split_named(spec, "--arm")
    runs = [summarise(p, dt) for p in expand(paths)]
    with_traffic = {r.hits is not None for r in runs}
    if len(with_traffic) > 1:
        raise ReportError(f"--arm `{name}`: mixes evaluations with and without traffic columns")
    return TrafficArm(name, runs, refs)


def cells(mean: dict[str, float | None], sd: dict[str, float | None] | None, refs: References) -> str:
    """The table's cells after the arm and run columns."""

    def cell(key: str, unit: str = "") -> str:
        m = mean[key]
        if m is None:
            return "–"
        s = sd[key] if sd else None
        return (f"{m:.1f} ± {s:.1f}" if s is not None else f"{m:.1f}") + unit

    gap = refs.gap(mean["avg_int"], mean["avg_ext"])
    keys = [("hits", ""), ("dont_walk", ""), ("bumps", ""), ("kerb_wait_s", " s")]
    return " | ".join([cell("avg_int"), cell("avg_ext"), gap, cell("success", " %"), *(cell(k, u) for k, u in keys)])


def per_run_table(arms: list[TrafficArm], column: str) -> str:
    lines = [f"| {column} | run | {HEADER} |", "|---|---|" + "---|" * 8]
    for arm in arms:
        for run in arm.runs:
            values = {k: getattr(run, k) for k in FIELDS}
            lines.append(f"| {arm.name} | {run.name} | {cells(values, None, arm.refs)} |")
    return "\n".join(lines)


def per_arm_table(arms: list[TrafficArm], column: str) -> str:
    lines = [f"| {column} | runs | {HEADER} |", "|---|---|" + "---|" * 8]
    for arm in arms:
        mean, sd = arm.statistics()
        lines.append(f"| {arm.name} | {len(arm.runs)} | {cells(mean, sd, arm.refs)} |")
    return "\n".join(lines)


def per_point_table(path: Path, dt: float = DEFAULT_DT) -> str:
    """Episodes, success, steps and safety counts per validation point of one evaluation."""
    file, rows = read_rows(path)
    counts = [c for c in (*SAFETY_COLUMNS, "vehicle_bumps") if c in rows[0]]
    wait = "kerb_wait_steps" in rows[0]
    head = ["point", "episodes", "success", "mean steps", *(f"{c} / 100" for c in counts)]
    head += ["mean kerb wait"] if wait else []

    def line(label: str, rs: list[dict[str, str]]) -> str:
        mean = lambda c: sum(float(r[c]) for r in rs) / len(rs)  # noqa: E731
        cols = [label, str(len(rs)), f"{100 * sum(map(is_success, rs)) / len(rs):.1f} %", f"{mean('steps'):.0f}"]
        cols += [f"{100 * mean(c):.1f}" for c in counts]
        cols += [f"{mean('kerb_wait_steps') * dt:.1f} s"] if wait else []
        return "| " + " | ".join(cols) + " |"

    try:
        by_point: dict[int, list[dict[str, str]]] = defaultdict(list)
        for row in rows:
            by_point[int(row["point"])].append(row)
        body = [line(str(point), by_point[point]) for point in sorted(by_point)] + [line("all", rows)]
    except (TypeError, ValueError) as e:
        raise ReportError(f"{file}: cannot read its rows ({e})") from e
    return "\n".join(["| " + " | ".join(head) + " |", "|" + "---|" * len(head), *body])


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m pednav_report.traffic",
        description="The traffic tables (returns, gap closed, success, vehicle hits, don't-walk entries, walker "
        "bumps, kerb wait) from pednav-eval's per-episode results.csv: per run, then per arm (mean ± sample "
        "standard deviation). Descriptive; a comparison of arms goes through `python -m pednav_report`.",
    )
    p.add_argument(
        "--arm",
        action="append",
        default=[],
        metavar="NAME=PATHS",
        help="an arm: comma-separated results.csv files, run directories (their eval/learned/results.csv), "
        "folders holding a results.csv, or globs; repeat for every arm, in table order",
    )
    p.add_argument(
        "--refs",
        type=Path,
        help="folder with random/ and oracle/ results.csv evaluated with the same traffic "
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
    p.add_argument("--per-point", type=Path, metavar="PATH", help="print one evaluation's per-point table instead")
    return p


def render(args: argparse.Namespace) -> str:
    if not args.dt > 0:
        raise ReportError(f"--dt {args.dt}: must be > 0 seconds")
    if args.per_point is not None:
        return per_point_table(args.per_point, args.dt)
    if not args.arm:
        raise ReportError("give at least one --arm NAME=PATHS (or --per-point PATH)")
    if args.refs is None:
        raise ReportError("--refs FOLDER is required with --arm (random/ and oracle/ evaluated with the traffic)")
    refs = References.load(args.refs, args.dt)
    other = dict(split_named(spec, "--refs-for", "FOLDER") for spec in args.refs_for)
    arms = []
    for spec in args.arm:
        arm = read_arm(spec, refs, args.dt)
        folder = other.pop(arm.name, None)
        arms.append(arm if folder is None else TrafficArm(arm.name, arm.runs, References.load(Path(folder), args.dt)))
    if other:
        raise ReportError(f"--refs-for names no --arm: {sorted(other)}")
    tables = [] if args.arms_only else [per_run_table(arms, args.column)]
    return "\n\n".join([*tables, per_arm_table(arms, args.column)])


def main(argv: list[str] | None = None) -> int:
    try:
        print(render(parser().parse_args(argv)))
    except ReportError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
