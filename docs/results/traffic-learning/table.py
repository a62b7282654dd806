# The results table of README.md, from each evaluation's per-episode results.csv:
#   python3 docs/results/traffic-learning/table.py
# Gap closed = (value - random) / (oracle - random) per average, with the references of
# the same traffic (../traffic-medium-references) or, for the run without traffic, of
# the recognisable scene without it (../references-recognisable).
import csv
import pathlib
import statistics

here = pathlib.Path(__file__).parent
refs = here.parent / "traffic-medium-references"
still = here.parent / "references-recognisable"


def summary(path):
    rows = list(csv.DictReader(open(path)))
    by = {}
    for r in rows:
        by.setdefault(int(r["point"]), []).append(float(r["discounted_return"]))
    means = {p: statistics.fmean(v) for p, v in by.items()}
    n = len(rows)
    per100 = lambda k: 100 * sum(float(r[k]) for r in rows) / n if k in rows[0] else None
    return {
        "int": statistics.fmean(m for p, m in means.items() if p < 8),
        "ext": statistics.fmean(m for p, m in means.items() if p >= 8),
        "success": sum(r["success"] == "true" for r in rows) / n,
        "hits": per100("vehicle_hits"),
        "dontwalk": per100("dont_walk_entries"),
        "bumps": per100("pedestrian_bumps"),
        "wait": sum(float(r["kerb_wait_steps"]) for r in rows) / n * 0.25 if "kerb_wait_steps" in rows[0] else None,
        "n": n,
    }



def arm_tables(runs, column):
    """Per-run rows, then per-arm mean +- sample std, of `runs` = [(arm, run label,
    run folder with eval/learned/results.csv)], gap closed against the medium-traffic
    references; `column` names the arm column. The tables of the traffic folders that
    compare arms over seeds (traffic-signal-phase, traffic-horizon)."""
    ref = {k: summary(refs / k / "results.csv") for k in ("random", "oracle")}
    gap = lambda v, k: (v - ref["random"][k]) / (ref["oracle"][k] - ref["random"][k])
    keys = ["int", "ext", "success", "hits", "dontwalk", "bumps", "wait"]
    head = (f"| {column} | {{}} | Avg.Int | Avg.Ext | gap closed (Int / Ext) | success | hits / 100 | "
            "don't-walk entries / 100 | walker bumps / 100 | mean kerb wait |\n|---|---|---|---|---|---|---|---|---|---|")
    print(head.format("run"))
    per_arm = {}
    for arm, label, folder in runs:
        path = folder / "eval" / "learned" / "results.csv"
        if not path.exists():
            continue
        s = summary(path)
        s["success"] *= 100
        per_arm.setdefault(arm, []).append(s)
        print(f"| {arm} | {label} | {s['int']:.1f} | {s['ext']:.1f} | {gap(s['int'], 'int'):.2f} / {gap(s['ext'], 'ext'):.2f} | "
              f"{s['success']:.1f} % | {s['hits']:.1f} | {s['dontwalk']:.1f} | {s['bumps']:.1f} | {s['wait']:.1f} s |")
    print()
    print(head.format("runs"))
    for arm, ss in per_arm.items():
        m = {k: statistics.fmean(s[k] for s in ss) for k in keys}
        sd = {k: statistics.stdev(s[k] for s in ss) for k in keys} if len(ss) > 1 else None
        pm = lambda k: f"{m[k]:.1f} ± {sd[k]:.1f}" if sd else f"{m[k]:.1f}"  # one run: no spread
        print(f"| {arm} | {len(ss)} | {pm('int')} | {pm('ext')} | {gap(m['int'], 'int'):.2f} / {gap(m['ext'], 'ext'):.2f} | "
              f"{pm('success')} % | {pm('hits')} | {pm('dontwalk')} | {pm('bumps')} | {pm('wait')} s |")


def main():
    traffic_ref = {k: summary(refs / k / "results.csv") for k in ("random", "oracle")}
    plain_ref = {k: summary(still / k / "results.csv") for k in ("random", "oracle")}

    def gap(s, ref):
        g = lambda a: (s[a] - ref["random"][a]) / (ref["oracle"][a] - ref["random"][a])
        return f"{g('int'):.2f} / {g('ext'):.2f}"

    arms = [
        ("oracle (waits for WALK), reference", refs / "oracle/results.csv", traffic_ref),
        ("random walk, reference", refs / "random/results.csv", traffic_ref),
        ("standing still, reference", here / "stand-still/results.csv", traffic_ref),
        ("**learned, t_max 2,000** (`medium-s1`)", here / "medium-s1/eval/learned/results.csv", traffic_ref),
        ("**learned, t_max 500** (`medium-tmax500-s1`)", here / "medium-tmax500-s1/eval/learned/results.csv", traffic_ref),
        ("learned, **no traffic**, for scale (`off-s1`)", here / "off-s1/eval/learned/results.csv", plain_ref),
    ]
    fmt = lambda v, f="{:.1f}": "–" if v is None else f.format(v)
    print("| policy | Avg.Int | Avg.Ext | gap closed (Int / Ext) | success | hits / 100 | don't-walk entries / 100 | walker bumps / 100 | mean kerb wait |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, path, ref in arms:
        if not path.exists():
            continue
        s = summary(path)
        print(f"| {name} | {s['int']:.1f} | {s['ext']:.1f} | {gap(s, ref)} | {100 * s['success']:.1f} % | "
              f"{fmt(s['hits'])} | {fmt(s['dontwalk'])} | {fmt(s['bumps'])} | {fmt(s['wait'], '{:.1f} s')} |")


if __name__ == "__main__":
    main()
