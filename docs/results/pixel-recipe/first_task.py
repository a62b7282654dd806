"""The first-task table of README.md: for each run, the mean discounted return (episodes,
success) of its first-task episodes per 25 k env steps up to 150 k, the best mean over 30
consecutive first-task episodes (the PassFirstTask statistic) and the env step at which
the gate opened (the curriculum service's record; where a run has none, ≤ the first
episode of another category). The recipe's three seeds, then
the paper's losses on the same scene (../scene-learning, seeds 1 and 2, 165 k env steps).

    python3 docs/results/pixel-recipe/first_task.py
    python3 docs/results/pixel-recipe/first_task.py "NAME=RUN_DIR" ...   # other runs
"""
import csv
import json
import statistics as st
import sys
from pathlib import Path

HERE = Path(__file__).parent
RUNS = {
    "recipe s1": HERE / "recipe-s1",
    "recipe s2": HERE / "recipe-s2",
    "recipe s3": HERE / "recipe-s3",
    "paper's s1": HERE.parent / "scene-learning" / "recognisable-s1",
    "paper's s2": HERE.parent / "scene-learning" / "recognisable-s2",
}
if len(sys.argv) > 1:
    RUNS = {name: Path(run) for name, run in (a.split("=", 1) for a in sys.argv[1:])}
WINDOW, UNTIL = 25_000, 150_000

rows = {}
for name, run in RUNS.items():
    path = run / "metrics" / "episodes.csv"
    if path.exists():
        with open(path) as f:
            rows[name] = list(csv.DictReader(f))

print("| env steps | " + " | ".join(rows) + " |")
print("|---|" + "---|" * len(rows))
for lo in range(0, UNTIL, WINDOW):
    cells = []
    for name, rs in rows.items():
        w = [r for r in rs if r["category"] == "first" and lo <= int(r["decision_steps"]) < lo + WINDOW]
        if not w:
            cells.append("—")
            continue
        ret = st.mean(float(r["discounted_return"]) for r in w)
        success = 100 * st.mean(int(r["success"]) for r in w)
        cells.append(f"{ret:.1f} ({len(w)}, {success:.0f} %)")
    print(f"| {lo // 1000}–{(lo + WINDOW) // 1000} k | " + " | ".join(cells) + " |")
best, opened = [], []
for name, rs in rows.items():
    first = [float(r["discounted_return"]) for r in rs if r["category"] == "first"]
    best.append(f"{max(st.mean(first[i:i + 30]) for i in range(len(first) - 29)):.1f}" if len(first) >= 30 else "—")
    # The curriculum service's own record (stats/curriculum.json), else the first episode
    # of another category (it follows the episode that opened the gate).
    stats = RUNS[name] / "stats" / "curriculum.json"
    passed = json.loads(stats.read_text()).get("first_task_passed") if stats.exists() else None
    if passed:
        opened.append(f"{passed['decision_steps']:,}")
    else:
        gate = next((int(r["decision_steps"]) for r in rs if r["category"] != "first"), None)
        opened.append(f"≤ {gate:,}" if gate is not None else "not opened")
print("| best 30-episode mean | " + " | ".join(best) + " |")
print("| gate opened by (env steps) | " + " | ".join(opened) + " |")
