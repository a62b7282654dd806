# Safety counts per validation point and per 100 episodes from a results.csv of pednav-eval with traffic:
#   python3 safety.py oracle/results.csv
import csv, collections, sys
rows=list(csv.DictReader(open(sys.argv[1])))
by=collections.defaultdict(list)
for r in rows: by[int(r['point'])].append(r)
print("pt  succ  steps  hits dontwalk pedbump vehbump kerbwait(s)")
for p in sorted(by):
    rs=by[p]; n=len(rs)
    f=lambda k: sum(float(r[k]) for r in rs)/n
    print(p, f"{sum(r['success']=='true' for r in rs)/n:.2f}", f"{f('steps'):.0f}", f"{f('vehicle_hits'):.2f}", f"{f('dont_walk_entries'):.2f}", f"{f('pedestrian_bumps'):.2f}", f"{f('vehicle_bumps'):.2f}", f"{f('kerb_wait_steps')*0.25:.1f}")
n=len(rows); f=lambda k: 100*sum(float(r[k]) for r in rows)/n
print(f"all {n}: success {sum(r['success']=='true' for r in rows)/n:.3f}; per 100 episodes: hits {f('vehicle_hits'):.1f}, don't-walk entries {f('dont_walk_entries'):.1f}, pedestrian bumps {f('pedestrian_bumps'):.1f}, vehicle bumps {f('vehicle_bumps'):.1f}; mean kerb wait {sum(float(r['kerb_wait_steps']) for r in rows)/n*0.25:.1f} s")
