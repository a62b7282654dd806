# The tables of README.md, from each evaluation's per-episode results.csv:
#   python3 docs/results/traffic-warm-start/table.py
# Per run: Avg.Int / Avg.Ext (means of the point means over points 0-7 / 8-13), success
# and the safety counts per 100 episodes; per arm: mean +- sample standard deviation
# over its runs; gap closed against the medium-traffic references
# (../traffic-medium-references). The arithmetic is traffic-learning/table.py's.
import importlib.util
import pathlib

here = pathlib.Path(__file__).parent
_spec = importlib.util.spec_from_file_location("traffic_learning", here.parent / "traffic-learning" / "table.py")
traffic_learning = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(traffic_learning)

# (arm, run label, run folder with eval/learned/results.csv)
runs = [
    ("from scratch, 300 k with traffic", "seed 1", here.parent / "traffic-learning" / "medium-s1"),
    ("from scratch, 300 k with traffic", "seed 2", here.parent / "traffic-signal-phase" / "drawn-s2"),
    ("no-traffic recipe policy, evaluated with traffic", "seed 1", here / "no-traffic-policy-s1"),
    ("no-traffic recipe policy, evaluated with traffic", "seed 2", here / "no-traffic-policy-s2"),
    ("warm start, 300 k without + 300 k with traffic", "seed 1", here / "warm-s1"),
    ("warm start, 300 k without + 300 k with traffic", "seed 2", here / "warm-s2"),
]
traffic_learning.arm_tables(runs, "training")
