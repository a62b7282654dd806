"""The first-task table of README.md: mean discounted return (episodes, success) of the
first-task episodes per 25 k env steps, for each pilot and the matched baseline (the
recognisable scene, seed 2, of ../scene-learning), and the best mean over 30
consecutive first-task episodes (the PassFirstTask statistic). Windows past a run's
last episode are left empty.

    python3 docs/results/pixel-recipe-pilots/first_task.py
"""
import csv
import statistics as st
from pathlib import Path

HERE = Path(__file__).parent
RUNS = {
    "paper's (baseline)": HERE.parent / "scene-learning" / "recognisable-s2",
    "fast lr": HERE / "fastlr-s2",
    "3-step": HERE / "nstep3-s2",
    "contrast": HERE / "contrast-s2",
}
BUDGET = 165_017

data = {}
for name, run in RUNS.items():
    with open(run / "metrics" / "episodes.csv") as f:
        data[name] = [r for r in csv.DictReader(f) if r["category"] == "first" and int(r["decision_steps"]) <= BUDGET]

print("| env steps | " + " | ".join(RUNS) + " |")
print("|---|" + "---|" * len(RUNS))
for lo in range(0, BUDGET, 25_000):
    cells = []
    for name in RUNS:
        w = [r for r in data[name] if lo <= int(r["decision_steps"]) < lo + 25_000]
        if not w:
            cells.append("—")
            continue
        ret = st.mean(float(r["discounted_return"]) for r in w)
        success = 100 * st.mean(int(r["success"]) for r in w)
        cells.append(f"{ret:.1f} ({len(w)}, {success:.0f} %)")
    print(f"| {lo // 1000}–{min(lo + 25_000, BUDGET) // 1000} k | " + " | ".join(cells) + " |")
best = []
for name in RUNS:
    rs = [float(r["discounted_return"]) for r in data[name]]
    best.append(f"{max(st.mean(rs[i:i + 30]) for i in range(len(rs) - 29)):.1f}" if len(rs) >= 30 else "—")
print("| best 30-episode mean | " + " | ".join(best) + " |")
