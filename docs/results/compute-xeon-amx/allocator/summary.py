"""The allocator A/B of this folder: `python3 summary.py` (from this folder or anywhere).
Reads bench/{OLD,NEW}-{round}.json (dsac_update --json) and bench/page-faults-*.txt
(perf stat), prints per case the medians of each round and the mean of them."""
import glob, json, os, re, statistics

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'bench')
OLD, NEW = '6fcd41d', 'mi2'
CASES = ['a', 'b', 'c', 'd', 'd_twin', 'd_recipe', 'd_recipe_bf16',
         'act_full_1', 'act_cache_1', 'act_full_16', 'act_cache_16']


def rounds(tag):
    return [json.load(open(f)) for f in sorted(glob.glob(f'{HERE}/{tag}-[0-9].json'))]


def faults(tag):
    out = []
    for f in sorted(glob.glob(f'{HERE}/page-faults-{tag}-[0-9].txt')):
        m = re.search(r'([\d,]+)\s+page-faults', open(f).read())
        out.append(int(m.group(1).replace(',', '')))
    return out


old, new = rounds(OLD), rounds(NEW)
print(f'{len(old)} rounds of {OLD} (glibc malloc) and {len(new)} of {NEW} (mimalloc), alternated')
print('| case | glibc: median ms per round | mimalloc: median ms per round | mean glibc / mean mimalloc |')
print('|---|---|---|---|')
for c in CASES:
    o = [r[c]['median_ms'] for r in old if c in r]
    n = [r[c]['median_ms'] for r in new if c in r]
    if not o or not n:
        continue
    fmt = lambda v: ' / '.join(f'{x:.1f}' if x >= 10 else f'{x:.2f}' for x in v)
    print(f'| {c} | {fmt(o)} | {fmt(n)} | **{statistics.mean(o) / statistics.mean(n):.2f}×** |')
print(f'| page faults, whole bench process | {" / ".join(f"{x:,}" for x in faults(OLD))} | '
      f'{" / ".join(f"{x:,}" for x in faults(NEW))} | |')
