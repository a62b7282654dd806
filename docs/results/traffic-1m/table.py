# The tables of README.md, from each evaluation's per-episode results.csv:
#   python3 docs/results/traffic-1m/table.py
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
    ("γ 0.998, 300 k env steps", "seed 1", here.parent / "traffic-horizon" / "g998-s1"),
    ("γ 0.998, 300 k env steps", "seed 2", here.parent / "traffic-horizon" / "g998-s2"),
    ("γ 0.998, 1 M env steps", "seed 1", here / "g998-s1"),
]
traffic_learning.arm_tables(runs, "budget")
