"""The 1 M verdicts with 95 % t-intervals over seeds, and the ablations' intervals (issue 57, item 3).

    python3 docs/results/recipe-1m/verdicts.py              # the 1 M arms (recipe-1m, recipe-enlarged-1m)
    python3 docs/results/recipe-1m/verdicts.py --ablations  # the pixel ablations against the recipe

Per run, from its per-episode `eval/learned/results.csv` (sampled protocol, 14 points ×
8 yaws × 10 runs): Avg.Int and Avg.Ext (the mean of the per-point mean discounted returns
over points 0–7 and 8–13), success (share of its episodes), and the share of the
random→oracle gap closed, (value − random) / (oracle − random), with the recognisable
scene's references (`../references-recognisable/{random,oracle}/table.csv`). Per arm: the
mean over seeds and a 95 % t-interval, mean ± t(0.975, n − 1) · s / √n (s the sample
standard deviation; success clipped to [0, 100] %). Verdict against a goal "≥ g": "met"
when the whole interval is ≥ g, "short" when it is all below g, else "inside the seeds'
noise". Each run's precision, CPU and binaries are printed beside it (from the folders'
READMEs and `config.toml`'s `nets.conv_precision`), and every arm that pools precisions
or machines is also given on its subset of one precision (or one machine and binaries).

The ablations (`--ablations`: `../pixel-ablations` and the two bf16 arms of `../bf16-recipe`): per arm the mean [95 % t-interval] of Avg.Int and Avg.Ext,
and its difference from the recipe's (`../pixel-recipe`, seeds 1–3) with a Welch
interval (degrees of freedom by Welch–Satterthwaite, rounded down: conservative).

Standard library only (scipy's t quantile if it is installed; the same values otherwise
from the table below).
"""

from __future__ import annotations

import csv
import math
import statistics
import sys
from pathlib import Path

RESULTS = Path(__file__).resolve().parents[1]

# t(0.975, df), df = 1 … 10
T975 = [12.7062, 4.3027, 3.1824, 2.7764, 2.5706, 2.4469, 2.3646, 2.3060, 2.2622, 2.2281]


def t975(df: int) -> float:
    try:
        from scipy.stats import t  # type: ignore

        return float(t.ppf(0.975, df))
    except ImportError:
        return T975[df - 1]


def reference(name: str) -> tuple[float, float]:
    with (RESULTS / "references-recognisable" / name / "table.csv").open(newline="") as f:
        rows = {row["point"]: row for row in csv.DictReader(f)}
    return float(rows["avg_int"]["mean"]), float(rows["avg_ext"]["mean"])


RANDOM = reference("random")
ORACLE = reference("oracle")


def precision(run: Path) -> str:
    """`nets.conv_precision` of the run's resolved config; absent before the option existed (f32)."""
    for line in (run / "config.toml").read_text(encoding="utf-8").splitlines():
        if line.strip().startswith("conv_precision"):
            return line.split("=", 1)[1].strip().strip('"')
    return "(none: f32)"


def evaluate(run: Path) -> dict[str, float]:
    """Avg.Int, Avg.Ext, success and gap closed of one run, from its per-episode results."""
    returns: dict[int, list[float]] = {}
    successes = []
    with (run / "eval" / "learned" / "results.csv").open(newline="") as f:
        for row in csv.DictReader(f):
            returns.setdefault(int(row["point"]), []).append(float(row["discounted_return"]))
            successes.append(row["success"].strip().lower() == "true")
    assert sorted(returns) == list(range(14)) and len(successes) == 1120, run
    per_point = {p: statistics.fmean(v) for p, v in returns.items()}
    avg_int = statistics.fmean(per_point[p] for p in range(0, 8))
    avg_ext = statistics.fmean(per_point[p] for p in range(8, 14))
    # The same as the evaluator's own table.csv (4 decimals).
    with (run / "eval" / "learned" / "table.csv").open(newline="") as f:
        table = {row["point"]: float(row["mean"]) for row in csv.DictReader(f) if row["point"].startswith("avg")}
    assert abs(table["avg_int"] - avg_int) < 1e-3 and abs(table["avg_ext"] - avg_ext) < 1e-3, run
    return {
        "avg_int": avg_int,
        "avg_ext": avg_ext,
        "success": 100.0 * sum(successes) / len(successes),
        "gap_int": (avg_int - RANDOM[0]) / (ORACLE[0] - RANDOM[0]),
        "gap_ext": (avg_ext - RANDOM[1]) / (ORACLE[1] - RANDOM[1]),
    }


def interval(values: list[float], clip: tuple[float, float] | None = None) -> tuple[float, float, float]:
    n = len(values)
    mean = statistics.fmean(values)
    half = t975(n - 1) * statistics.stdev(values) / math.sqrt(n)
    lo, hi = mean - half, mean + half
    if clip:
        lo, hi = max(lo, clip[0]), min(hi, clip[1])
    return mean, lo, hi


def verdict(lo: float, hi: float, goal: float) -> str:
    if lo >= goal:
        return "met"
    if hi < goal:
        return "short"
    return "inside the seeds' noise"


# Each 1 M run: folder, precision, CPU and binaries (docs/results/recipe-1m/README.md,
# docs/results/recipe-enlarged-1m/README.md; "auto" is bf16 on these CPUs, ibid.).
M, X = RESULTS / "recipe-1m", RESULTS / "recipe-enlarged-1m"
ZEN4, XEON = "2-core AMD EPYC Zen 4", "2-vCPU Intel Xeon (AMX)"
RUNS_1M = {
    "default preset": [
        ("s1", M / "s1", "f32", ZEN4, "ac8e093"),
        ("s2", M / "s2", "f32", ZEN4, "0b88bbf"),
        ("s3", M / "s3", "f32", XEON, "79fb1cb"),
        ("s4", M / "s4", "bf16 (AMX tiles)", XEON, "1428b2b"),
    ],
    "enlarged region": [
        ("s1", X / "s1", "bf16 (AVX-512 BF16)", ZEN4, "73d6fde"),
        ("s2", X / "s2", "bf16 (AVX-512 BF16)", ZEN4, "73d6fde"),
        ("s3", X / "s3", "bf16 (AVX-512 BF16)", ZEN4, "73d6fde"),
        ("s4", X / "s4", "bf16 (AMX tiles)", XEON, "18755c1"),
    ],
}
# The rows of the verdict table: arm, which runs, what they pool.
GROUPS_1M = [
    ("default preset", ["s1", "s2", "s3", "s4"], "f32 ×3 + bf16 ×1; Zen 4 ×2 + Xeon ×2"),
    ("default preset", ["s1", "s2", "s3"], "f32 only; Zen 4 ×2 + Xeon ×1"),
    ("enlarged region", ["s1", "s2", "s3", "s4"], "bf16 ×4; Zen 4 ×3 + Xeon ×1"),
    ("enlarged region", ["s1", "s2", "s3"], "bf16, one machine and binaries (Zen 4, 73d6fde)"),
]
GOALS = [("Avg.Int gap closed", "gap_int", 0.85, "{:.2f}", None),
         ("Avg.Ext gap closed", "gap_ext", 0.80, "{:.2f}", None),
         ("success (%)", "success", 95.0, "{:.1f}", (0.0, 100.0))]


def one_million() -> None:
    measured = {arm: {name: evaluate(path) for name, path, *_ in runs} for arm, runs in RUNS_1M.items()}
    print("| arm | run | precision | `conv_precision` | CPU | binaries | Avg.Int | Avg.Ext | gap closed Int / Ext | success |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for arm, runs in RUNS_1M.items():
        for name, path, prec, cpu, commit in runs:
            m = measured[arm][name]
            config = precision(path)
            print(f"| {arm} | `{name}` | {prec} | {config} | {cpu} | {commit} | {m['avg_int']:.1f} | "
                  f"{m['avg_ext']:.1f} | {m['gap_int']:.2f} / {m['gap_ext']:.2f} | {m['success']:.1f} % |")
    print()
    print("| arm | runs (what they pool) | metric | mean [95 % CI] | goal | verdict |")
    print("|---|---|---|---|---|---|")
    for arm, names, pooled in GROUPS_1M:
        label = f"{', '.join(names)} (n = {len(names)}; {pooled})"
        for metric, key, goal, fmt, clip in GOALS:
            mean, lo, hi = interval([measured[arm][n][key] for n in names], clip)
            print(f"| {arm} | {label} | {metric} | {fmt.format(mean)} [{fmt.format(lo)}, {fmt.format(hi)}] | "
                  f"≥ {fmt.format(goal)} | {verdict(lo, hi, goal)} |")
    print()
    print(f"t(0.975, n − 1): n = 3 {t975(2):.3f}, n = 4 {t975(3):.3f}; success intervals clipped to [0, 100] %; "
          f"references: random {RANDOM[0]:.1f} / {RANDOM[1]:.1f}, oracle {ORACLE[0]:.1f} / {ORACLE[1]:.1f}.")


def welch(a: list[float], b: list[float]) -> tuple[float, float, float, int]:
    """mean(a) − mean(b), its 95 % Welch interval and the (rounded-down) degrees of freedom."""
    va, vb = statistics.variance(a) / len(a), statistics.variance(b) / len(b)
    df = (va + vb) ** 2 / (va**2 / (len(a) - 1) + vb**2 / (len(b) - 1))
    df_floor = max(1, math.floor(df))
    d = statistics.fmean(a) - statistics.fmean(b)
    half = t975(df_floor) * math.sqrt(va + vb)
    return d, d - half, d + half, df_floor


P, Q, B = RESULTS / "pixel-ablations", RESULTS / "pixel-recipe", RESULTS / "bf16-recipe"
ABLATIONS = [  # arm, run folders (docs/results/pixel-ablations/README.md)
    ("recipe", [Q / f"recipe-s{s}" for s in (1, 2, 3)]),
    ("no contrast", [P / f"nocontrast-s{s}" for s in (1, 2, 3)]),
    ("one critic", [P / f"onecritic-s{s}" for s in (1, 2)]),
    ("3-step returns", [P / f"nstep3-s{s}" for s in (1, 2)]),
    ("random shift ±2 px", [P / f"shift2-s{s}" for s in (1, 2)]),
    ("UTD 1/4, 2,000 s", [P / f"utd4-s{s}" for s in (1, 2)]),
    ("84², 2,000 s", [P / f"img84-s{s}" for s in (1, 2)]),
    # The precision arms that made "auto" the default (docs/results/bf16-recipe/README.md).
    ("bf16, AVX-512 BF16", [B / f"s{s}" for s in (1, 2, 3)]),
    ("bf16, AMX tiles", [B / f"amx-s{s}" for s in (1, 2, 3)]),
]


def ablations() -> None:
    measured = {arm: [evaluate(r) for r in runs] for arm, runs in ABLATIONS}
    recipe = measured["recipe"]
    print("| arm | n | `conv_precision` | Avg.Int [95 % CI] | Avg.Ext [95 % CI] | success [95 % CI] "
          "| Δ Avg.Int vs recipe [95 % CI] | Δ Avg.Ext vs recipe [95 % CI] |")
    print("|---|---|---|---|---|---|---|---|")
    for arm, runs in ABLATIONS:
        ms = measured[arm]
        cells = []
        for key, clip in (("avg_int", None), ("avg_ext", None), ("success", (0.0, 100.0))):
            mean, lo, hi = interval([m[key] for m in ms], clip)
            unit = " %" if key == "success" else ""
            cells.append(f"{mean:.1f} [{lo:.1f}, {hi:.1f}]{unit}")
        for key in ("avg_int", "avg_ext"):
            if arm == "recipe":
                cells.append("—")
                continue
            d, lo, hi, df = welch([m[key] for m in ms], [m[key] for m in recipe])
            cells.append(f"{d:+.1f} [{lo:+.1f}, {hi:+.1f}] (df {df})")
        precs = sorted({precision(r) for r in runs})
        print(f"| {arm} | {len(runs)} | {', '.join(precs)} | " + " | ".join(cells) + " |")
    print()
    print("t-intervals over seeds (n − 1 df); Δ: the arm's mean minus the recipe's (seeds 1–3), "
          "Welch interval with its df rounded down.")


if __name__ == "__main__":
    if sys.argv[1:] == ["--ablations"]:
        ablations()
    elif not sys.argv[1:]:
        one_million()
    else:
        sys.exit(__doc__)
