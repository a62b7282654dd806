"""``python -m pednav_report``: the command line (``--help``)."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from .data import DEFAULT_RESULTS, ReportError, load_reference, parse_arm
from .report import Settings, compute, write


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m pednav_report",
        description=(
            "rliable's reliable-evaluation statistics (IQM, optimality gap, stratified-bootstrap intervals, "
            "performance profiles, probability of improvement) and Welch/Holm tests on seed means, from "
            "pednav-eval's per-episode results.csv. Writes report.md, report.json and performance_profile.png."
        ),
    )
    p.add_argument(
        "--arm",
        action="append",
        required=True,
        metavar="NAME=PATHS",
        help="an arm: comma-separated results.csv files, run directories (their --results file) or globs; "
        "one run per seed; repeat for every arm",
    )
    p.add_argument(
        "--random",
        required=True,
        metavar="PATH",
        help="the random walk's evaluation: a results.csv (per (point, yaw) reference), a table.csv "
        "(per point, its `mean` column) or a directory holding one (results.csv preferred)",
    )
    p.add_argument(
        "--oracle",
        required=True,
        metavar="PATH|from-runs",
        help="the oracle's evaluation, as --random (a table.csv gives its `oracle` column), or `from-runs`: "
        "the `oracle` column of the runs' own table.csv (must agree across runs)",
    )
    p.add_argument("--out", required=True, type=Path, help="output directory")
    p.add_argument(
        "--results", default=DEFAULT_RESULTS, help=f"a run directory's results file (default {DEFAULT_RESULTS})"
    )
    p.add_argument(
        "--pair",
        action="append",
        metavar="X|Y",
        help="report only these pairs (arm names separated by |; repeat); default every pair in --arm order",
    )
    p.add_argument("--reps", type=int, default=50_000, help="bootstrap replicates for IQM / optimality gap (50,000)")
    p.add_argument("--poi-reps", type=int, default=2_000, help="replicates for the probability of improvement (2,000)")
    p.add_argument("--profile-reps", type=int, default=2_000, help="replicates for the profiles' bands (2,000)")
    p.add_argument("--seed", type=int, default=0, help="seed of NumPy's generator before each bootstrap (0)")
    p.add_argument("--level", type=float, default=0.95, help="interval level (0.95)")
    p.add_argument("--alpha", type=float, default=0.05, help="level of the Holm-adjusted Welch tests (0.05)")
    p.add_argument("--jobs", type=int, default=1, help="processes for the probability of improvement (1)")
    p.add_argument("--title", default="Reliable-evaluation statistics (rliable)", help="report.md's heading")
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    command = "python -m pednav_report " + " ".join(shlex.quote(a) for a in (sys.argv[1:] if argv is None else argv))
    try:
        arms = [parse_arm(a, args.results) for a in args.arm]
        runs = [r for a in arms for r in a.runs]
        random = load_reference(args.random, "random")
        oracle = load_reference(args.oracle, "oracle", runs)
        pairs = None
        if args.pair:
            pairs = []
            for p in args.pair:
                x, sep, y = p.partition("|")
                if not sep:
                    raise ReportError(f"--pair `{p}`: expected X|Y")
                pairs.append((x.strip(), y.strip()))
        settings = Settings(
            reps=args.reps,
            poi_reps=args.poi_reps,
            profile_reps=args.profile_reps,
            seed=args.seed,
            level=args.level,
            alpha=args.alpha,
            jobs=args.jobs,
            pairs=pairs,
            command=command,
            title=args.title,
        )
        result = compute(arms, random, oracle, settings)
        write(result, args.out)
    except ReportError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    for w in result["warnings"]:
        print(f"warning: {w}", file=sys.stderr)
    print(f"wrote {args.out}/report.md, report.json, performance_profile.png", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
