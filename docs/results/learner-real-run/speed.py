"""The before/after tables of README.md: env steps per second after the first minute and
the median update time of each fixed-length run, from its `learner.csv`.

    python3 docs/results/learner-real-run/speed.py                  # the fused-optimiser table
    python3 docs/results/learner-real-run/speed.py "label=FOLDER" …  # any runs (FOLDER holds
                                                                     # learner.csv or metrics/learner.csv)
"""
import csv
import statistics as st
import sys
from pathlib import Path

HERE = Path(__file__).parent
RUNS = {"after, 1st": "after-1", "before, 1st": "before-1", "after, 2nd": "after-2", "before, 2nd": "before-2"}
if len(sys.argv) > 1:
    RUNS = dict(arg.rsplit("=", 1) for arg in sys.argv[1:])

print("| run | env steps / s after the first minute | median update | env steps in total | wall |")
print("|---|---|---|---|---|")
for label, name in RUNS.items():
    folder = HERE / name
    csv_path = next(p for p in (folder / "learner.csv", folder / "metrics" / "learner.csv") if p.exists())
    with open(csv_path) as f:
        rows = list(csv.DictReader(f))
    late = [r for r in rows if float(r["elapsed_s"]) > 60]
    first, last = late[0], rows[-1]
    rate = (float(last["step"]) - float(first["step"])) / (float(last["elapsed_s"]) - float(first["elapsed_s"]))
    update = st.median(float(r["update_ms"]) for r in late if r["update_ms"])
    print(f"| {label} | {rate:.1f} | {update:.1f} ms | {int(last['step']):,} | {float(last['elapsed_s']):.0f} s |")
