# The results table of README.md from the folders' traffic-probe.json:
#   python3 docs/results/traffic-probes/table.py
import json
import pathlib

here = pathlib.Path(__file__).parent
probes = [("walk_one_frame", "WALK, one frame"), ("walk_history", "WALK, history"),
          ("vehicle_one_frame", "vehicle ≤ 3 s, one frame"), ("vehicle_history", "vehicle ≤ 3 s, history")]
print("| frames | probe | held-out accuracy | majority class | balanced accuracy | training accuracy | epochs |")
print("|---|---|---|---|---|---|---|")
for run in sorted(p.parent for p in here.glob("*/traffic-probe.json")):
    j = json.loads((run / "traffic-probe.json").read_text())
    frames = f"{j['image_size']}²" + (f", {j['supersample']}×{j['supersample']} samples" if j.get("supersample", 1) > 1 else "")
    frames += f", {j['fov_deg']:g}° lens" if j.get("fov_deg", 135.0) != 135.0 else ""
    frames += f", ground signals {j['ground_signals']}" if j.get("ground_signals", "off") != "off" else ""
    for key, name in probes:
        r = j["probes"].get(key)
        if r is None:
            continue
        hist = f" (N_h {j['history']})" if key.endswith("history") else ""
        print(f"| {frames} (`{run.name}`) | {name}{hist} | {100 * r['test_accuracy']:.1f} % | "
              f"{100 * r['test_majority']:.1f} % | **{100 * r['test_balanced_accuracy']:.1f} %** | "
              f"{100 * r['train_accuracy']:.1f} % | {j['epochs']} |")
