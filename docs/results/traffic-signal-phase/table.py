# The tables of README.md, from each evaluation's per-episode results.csv:
#   python3 docs/results/traffic-signal-phase/table.py
# Per run: Avg.Int / Avg.Ext (means of the point means over points 0-7 / 8-13), success
# and the safety counts per 100 episodes; per arm: mean +- sample standard deviation
# over its runs. Gap closed against the medium-traffic references
# (../traffic-medium-references).
import csv
import pathlib
import statistics

here = pathlib.Path(__file__).parent
refs = here.parent / "traffic-medium-references"


def summary(path):
    rows = list(csv.DictReader(open(path)))
    by = {}
    for r in rows:
        by.setdefault(int(r["point"]), []).append(float(r["discounted_return"]))
    means = {p: statistics.fmean(v) for p, v in by.items()}
    n = len(rows)
    per100 = lambda k: 100 * sum(float(r[k]) for r in rows) / n
    return {
        "int": statistics.fmean(m for p, m in means.items() if p < 8),
        "ext": statistics.fmean(m for p, m in means.items() if p >= 8),
        "success": 100 * sum(r["success"] == "true" for r in rows) / n,
        "hits": per100("vehicle_hits"),
        "dontwalk": per100("dont_walk_entries"),
        "bumps": per100("pedestrian_bumps"),
        "wait": sum(float(r["kerb_wait_steps"]) for r in rows) / n * 0.25,
        "n": n,
    }


ref = {k: summary(refs / k / "results.csv") for k in ("random", "oracle")}
gap = lambda v, k: (v - ref["random"][k]) / (ref["oracle"][k] - ref["random"][k])

# (arm, run label, folder with eval/learned/results.csv)
runs = [
    ("drawn", "seed 1", here.parent / "traffic-learning" / "medium-s1"),
    ("drawn", "seed 2", here / "drawn-s2"),
    ("task", "seed 1", here / "task-s1"),
    ("task", "seed 2", here / "task-s2"),
]
keys = ["int", "ext", "success", "hits", "dontwalk", "bumps", "wait"]
print("| signal phase | run | Avg.Int | Avg.Ext | gap closed (Int / Ext) | success | hits / 100 | don't-walk entries / 100 | walker bumps / 100 | mean kerb wait |")
print("|---|---|---|---|---|---|---|---|---|---|")
per_arm = {}
for arm, label, folder in runs:
    path = folder / "eval" / "learned" / "results.csv"
    if not path.exists():
        continue
    s = summary(path)
    per_arm.setdefault(arm, []).append(s)
    print(f"| `{arm}` | {label} | {s['int']:.1f} | {s['ext']:.1f} | {gap(s['int'], 'int'):.2f} / {gap(s['ext'], 'ext'):.2f} | "
          f"{s['success']:.1f} % | {s['hits']:.1f} | {s['dontwalk']:.1f} | {s['bumps']:.1f} | {s['wait']:.1f} s |")
print()
print("| signal phase | runs | Avg.Int | Avg.Ext | gap closed (Int / Ext) | success | hits / 100 | don't-walk entries / 100 | walker bumps / 100 | mean kerb wait |")
print("|---|---|---|---|---|---|---|---|---|---|")
for arm, ss in per_arm.items():
    m = {k: statistics.fmean(s[k] for s in ss) for k in keys}
    sd = {k: statistics.stdev(s[k] for s in ss) if len(ss) > 1 else float("nan") for k in keys}
    pm = lambda k, f="{:.1f}": f"{f.format(m[k])} ± {f.format(sd[k])}"
    print(f"| `{arm}` | {len(ss)} | {pm('int')} | {pm('ext')} | {gap(m['int'], 'int'):.2f} / {gap(m['ext'], 'ext'):.2f} | "
          f"{pm('success')} % | {pm('hits')} | {pm('dontwalk')} | {pm('bumps')} | {pm('wait')} s |")
