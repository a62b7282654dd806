# Training curve of a traffic run from its per-episode log (metrics/episodes.csv):
#   python3 docs/results/traffic-1m/curve.py [RUN ...]
# For every 100 k decision steps (= env steps) of the run: episodes that ended in the
# window, the share that reached the goal, the share cut at T_max, the mean discounted
# return, and the same for episodes started far from the goal (the curriculum's tasks
# more than 15 m away, straight line). Training episodes start where the curriculum
# proposes, so these are not the protocol's figures (eval/learned/table.csv has those).
import csv
import math
import pathlib
import sys

here = pathlib.Path(__file__).parent
GOAL = (20.0, 7.0)  # the reference corner's goal centre (shared/sim/scenes/corner.toml)
WINDOW = 100_000


def rows(run):
    with open(pathlib.Path(run) / "metrics" / "episodes.csv") as f:
        for r in csv.DictReader(f):
            yield r


def curve(run):
    print(f"\n{run}")
    print("| decision steps | episodes | success | cut at T_max | mean return | far (> 15 m): episodes | far: success |")
    print("|---|---|---|---|---|---|---|")
    steps, win = 0, {}
    for r in rows(run):
        steps += int(r["length"])
        w = steps // WINDOW
        far = math.dist((float(r["x"]), float(r["y"])), GOAL) > 15.0
        b = win.setdefault(w, [0, 0, 0, 0.0, 0, 0])
        b[0] += 1
        b[1] += r["success"] == "1"
        b[2] += r["truncated"] == "1"
        b[3] += float(r["discounted_return"])
        b[4] += far
        b[5] += far and r["success"] == "1"
    for w in sorted(win):
        n, s, t, ret, nf, sf = win[w]
        far_s = f"{100 * sf / nf:.0f} %" if nf else "–"
        print(f"| {w * WINDOW // 1000}–{(w + 1) * WINDOW // 1000} k | {n} | {100 * s / n:.0f} % | {100 * t / n:.0f} % | {ret / n:.1f} | {nf} | {far_s} |")


for run in sys.argv[1:] or [here / "g998-s1"]:
    curve(run)
