"""The first-task table of README.md: mean discounted return (episodes, success) of the
first-task episodes per 25 k env steps, up to the runs' 165,017-step budget, and the
best mean over 30 consecutive first-task episodes (the PassFirstTask statistic).

    python3 docs/results/scene-learning/first_task.py
"""
import csv
import statistics as st
from pathlib import Path

HERE = Path(__file__).parent
RUNS = ["recognisable-s1", "plain-s1", "recognisable-s2", "plain-s2"]
BUDGET = 165_017

data = {}
for run in RUNS:
    with open(HERE / run / "metrics" / "episodes.csv") as f:
        data[run] = [r for r in csv.DictReader(f) if r["category"] == "first" and int(r["decision_steps"]) <= BUDGET]

print("| env steps | " + " | ".join(RUNS) + " |")
print("|---|" + "---|" * len(RUNS))
for lo in range(0, BUDGET, 25_000):
    cells = []
    for run in RUNS:
        w = [r for r in data[run] if lo <= int(r["decision_steps"]) < lo + 25_000]
        if not w:
            cells.append("—")
            continue
        ret = st.mean(float(r["discounted_return"]) for r in w)
        success = 100 * st.mean(int(r["success"]) for r in w)
        cells.append(f"{ret:.1f} ({len(w)}, {success:.0f} %)")
    print(f"| {lo // 1000}–{min(lo + 25_000, BUDGET) // 1000} k | " + " | ".join(cells) + " |")
best = []
for run in RUNS:
    rs = [float(r["discounted_return"]) for r in data[run]]
    best.append(f"{max(st.mean(rs[i:i + 30]) for i in range(len(rs) - 29)):.1f}")
print("| best 30-episode mean | " + " | ".join(best) + " |")
