"""The before/after table of README.md: env steps per second after the first minute and
the median update time of each fixed-length run, from its `metrics/learner.csv`.

    python3 docs/results/learner-real-run/speed.py
"""
import csv
import statistics as st
from pathlib import Path

HERE = Path(__file__).parent
RUNS = {"after, 1st": "after-1", "before, 1st": "before-1", "after, 2nd": "after-2", "before, 2nd": "before-2"}

print("| run | env steps / s after the first minute | median update | env steps in total | wall |")
print("|---|---|---|---|---|")
for label, name in RUNS.items():
    with open(HERE / name / "learner.csv") as f:
        rows = list(csv.DictReader(f))
    late = [r for r in rows if float(r["elapsed_s"]) > 60]
    first, last = late[0], rows[-1]
    rate = (float(last["step"]) - float(first["step"])) / (float(last["elapsed_s"]) - float(first["elapsed_s"]))
    update = st.median(float(r["update_ms"]) for r in late if r["update_ms"])
    print(f"| {label} | {rate:.1f} | {update:.1f} ms | {int(last['step']):,} | {float(last['elapsed_s']):.0f} s |")
