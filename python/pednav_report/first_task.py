"""First-task tables: how each run's PassFirstTask episodes went, per window of env steps.

``python -m pednav_report.first_task "NAME=RUN_DIR" …`` reads each run's
``metrics/episodes.csv`` (the learner's per-episode log: ``category``,
``decision_steps`` — env steps when the episode ended —, ``discounted_return``,
``success``) and prints one markdown table, a column per run:

- per window of ``--window`` env steps (25 k) up to ``--until``: the mean discounted
  return of the first-task episodes that ended in it, with their count and success
  share, ``—`` where none did;
- the best mean over 30 consecutive first-task episodes (the PassFirstTask statistic,
  ``—`` with fewer than 30);
- with ``--gate``, the env step at which the gate opened: the curriculum service's
  record (``stats/curriculum.json``'s ``first_task_passed``), else "≤" the first
  episode of another category (it follows the episode that opened the gate).

``--budget N`` counts only episodes that ended by env step N (runs cut at a common
budget); the windows then end at N unless ``--until`` says otherwise. A row counts the
episodes that ended in [start, end) of its label; the last row's end, ``--until``, is
included. Standard library only.
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import sys
from dataclasses import dataclass
from pathlib import Path

from .common import ReportError, split_named

#: The PassFirstTask statistic's window, in episodes.
GATE_EPISODES = 30


@dataclass(frozen=True)
class FirstTaskEpisode:
    env_steps: int
    discounted_return: float
    success: bool


@dataclass(frozen=True)
class RunEpisodes:
    """One run's first-task episodes (in the order they ended) and its gate."""

    name: str
    first: list[FirstTaskEpisode]
    gate: str


def read_run(name: str, run: Path, budget: int | None) -> RunEpisodes:
    """A run's first-task episodes that ended by ``budget`` and when its gate opened."""
    path = Path(run) / "metrics" / "episodes.csv"
    try:
        with path.open(newline="") as f:
            rows = list(csv.DictReader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise ReportError(f"{path}: {e} (is {run} a run directory?)") from e
    first, other_at = [], None
    for line, row in enumerate(rows, start=2):
        try:
            steps = int(row["decision_steps"])
            if budget is not None and steps > budget:
                continue
            if row["category"] == "first":
                first.append(FirstTaskEpisode(steps, float(row["discounted_return"]), int(row["success"]) != 0))
            elif other_at is None:
                other_at = steps
        except (KeyError, TypeError, ValueError) as e:
            raise ReportError(f"{path}: line {line}: cannot read {row} ({e})") from e
    stats = Path(run) / "stats" / "curriculum.json"
    try:
        passed = json.loads(stats.read_text()).get("first_task_passed") if stats.is_file() else None
        gate_step = int(passed["decision_steps"]) if passed else None
    except (OSError, UnicodeDecodeError, ValueError, TypeError, KeyError, AttributeError) as e:
        raise ReportError(f"{stats}: cannot read first_task_passed.decision_steps ({e!r})") from e
    if gate_step is not None:
        gate = f"{gate_step:,}"
    else:
        gate = f"≤ {other_at:,}" if other_at is not None else "not opened"
    return RunEpisodes(name, first, gate)


def window_cell(episodes: list[FirstTaskEpisode], lo: int, hi: int, last: bool) -> str:
    """Mean return (count, success) of the episodes that ended in [lo, hi), or [lo, hi]
    for the last row."""
    w = [e for e in episodes if lo <= e.env_steps < hi or (last and e.env_steps == hi)]
    if not w:
        return "—"
    ret = statistics.mean(e.discounted_return for e in w)
    success = 100 * statistics.mean(int(e.success) for e in w)
    return f"{ret:.1f} ({len(w)}, {success:.0f} %)"


def best_window(episodes: list[FirstTaskEpisode]) -> str:
    """The best mean over 30 consecutive first-task episodes (the PassFirstTask statistic)."""
    r = [e.discounted_return for e in episodes]
    if len(r) < GATE_EPISODES:
        return "—"
    return f"{max(statistics.mean(r[i : i + GATE_EPISODES]) for i in range(len(r) - GATE_EPISODES + 1)):.1f}"


def table(runs: list[RunEpisodes], window: int, until: int, gate: bool) -> str:
    """The markdown table, a column per run."""
    lines = ["| env steps | " + " | ".join(r.name for r in runs) + " |", "|---|" + "---|" * len(runs)]
    for lo in range(0, until, window):
        hi = min(lo + window, until)
        cells = [window_cell(r.first, lo, hi, hi == until) for r in runs]
        lines.append(f"| {lo // 1000}–{hi // 1000} k | " + " | ".join(cells) + " |")
    lines.append("| best 30-episode mean | " + " | ".join(best_window(r.first) for r in runs) + " |")
    if gate:
        lines.append("| gate opened by (env steps) | " + " | ".join(r.gate for r in runs) + " |")
    return "\n".join(lines)


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m pednav_report.first_task",
        description="Each run's first-task (PassFirstTask) episodes per window of env steps, the best "
        "30-episode mean and, with --gate, when the gate opened; from metrics/episodes.csv.",
    )
    p.add_argument("runs", nargs="+", metavar="NAME=RUN_DIR", help="a column: its heading and run directory")
    p.add_argument("--window", type=int, default=25_000, help="env steps per row (25,000)")
    p.add_argument("--until", type=int, help="last window's end (default: --budget, else 150,000)")
    p.add_argument("--budget", type=int, help="count only episodes that ended by this env step")
    p.add_argument("--gate", action="store_true", help="add the row of the env step the gate opened at")
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        for flag in ("window", "until", "budget"):
            value = getattr(args, flag)
            if value is not None and value <= 0:
                raise ReportError(f"--{flag} {value}: must be a positive number of env steps")
        runs = []
        for spec in args.runs:
            name, run = split_named(spec, "run", "RUN_DIR")
            runs.append(read_run(name, Path(run), args.budget))
    except ReportError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    until = args.until or args.budget or 150_000
    print(table(runs, args.window, until, args.gate))
    return 0


if __name__ == "__main__":
    sys.exit(main())
