"""The held-out-pose table of README.md: for each checkpoint, the mean over the 40 starts of
`held_out_starts.csv` (10 poses that are not protocol points × 4 yaws) of the mean
discounted return of its 10 sampled episodes, and the share of the 400 episodes that
reach the goal, from each run's `eval/held-out/results.csv` (`pednav-eval --starts`).

    python3 docs/results/table3-recipe/held_out.py
"""
import csv
import statistics as st
from pathlib import Path

HERE = Path(__file__).parent
RECIPE = HERE.parent / "pixel-recipe"
GROUPS = {
    "NavACL⁺ (S)": [RECIPE / f"recipe-s{s}" for s in (1, 2, 3)],
    "NavACL": [HERE / f"navacl-s{s}" for s in (1, 2, 3)],
    "NavACL⁺ (H)": [HERE / f"navacl-plus-h-s{s}" for s in (1, 2, 3)],
    "Non-ACL-TCN": [HERE / f"non-acl-tcn-s{s}" for s in (1, 2, 3)],
    "FR-8": [HERE / f"fr8-s{s}" for s in (1, 2, 3)],
}

print("| variant | run | mean return over the 40 starts | success (400 episodes) |")
print("|---|---|---|---|")
for name, runs in GROUPS.items():
    means = []
    for run in runs:
        path = run / "eval" / "held-out" / "results.csv"
        if not path.exists():
            continue
        with open(path) as f:
            rows = list(csv.DictReader(f))
        per_start = {}
        for r in rows:
            per_start.setdefault((r["point"], r["yaw_deg"]), []).append(float(r["discounted_return"]))
        mean = st.mean(st.mean(v) for v in per_start.values())
        success = sum(r["success"] == "true" for r in rows) / len(rows)
        means.append(mean)
        print(f"| {name} | {run.name} | {mean:.1f} | {100 * success:.1f} % |")
    if len(means) > 1:
        print(f"| **{name}** | n = {len(means)} | **{st.mean(means):.1f} ± {st.stdev(means):.1f}** | |")
