"""The per-run table of README.md: wall time, env steps received, updates, median update
time and when the PassFirstTask gate opened, for every run of the ablation (and the
recipe's own runs it is compared with), from the files each results folder keeps.

    python3 docs/results/pixel-ablations/runs.py
"""
import csv
import json
import statistics as st
from pathlib import Path

HERE = Path(__file__).parent
RECIPE = HERE.parent / "pixel-recipe"
ARMS = {
    "recipe (fast critic + contrast)": [RECIPE / "recipe-s1", RECIPE / "recipe-s2", RECIPE / "recipe-s3"],
    "fast critic, no contrast": [HERE / "nocontrast-s1", HERE / "nocontrast-s2", HERE / "nocontrast-s3"],
    "one critic (recipe otherwise)": [HERE / "onecritic-s1", HERE / "onecritic-s2"],
    "3-step returns (recipe otherwise)": [HERE / "nstep3-s1", HERE / "nstep3-s2"],
    "random shift ±2 px (recipe otherwise)": [HERE / "shift2-s1", HERE / "shift2-s2"],
    "update-to-data 1/4, stopped at 2,000 s (recipe otherwise)": [HERE / "utd4-s1", HERE / "utd4-s2"],
    "84² frames, stopped at 2,000 s (recipe otherwise)": [HERE / "img84-s1", HERE / "img84-s2"],
}

print("| arm | run | wall time | env steps received | updates | median update | gate opened after (env steps) |")
print("|---|---|---|---|---|---|---|")
for arm, runs in ARMS.items():
    for run in runs:
        if not run.exists():
            print(f"| {arm} | {run.name} | (missing) | | | | |")
            continue
        with open(run / "metrics" / "learner.csv") as f:
            rows = list(csv.DictReader(f))
        last = rows[-1]
        update_ms = st.median(float(r["update_ms"]) for r in rows if r["update_ms"])
        gate = json.loads((run / "stats" / "curriculum.json").read_text()).get("first_task_passed")
        opened = f"{gate['decision_steps']:,}" if gate else "not opened"
        print(
            f"| {arm} | {run.name} | {float(last['elapsed_s']) / 60:.1f} min | {int(last['step']):,} "
            f"| {int(last['updates']):,} | {update_ms:.1f} ms | {opened} |"
        )
