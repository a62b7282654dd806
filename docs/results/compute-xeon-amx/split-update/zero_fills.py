"""Who calls memset on the update's thread: `python3 zero_fills.py FILE` for a
`perf record -F 99 --call-graph dwarf,16384 -t TID -- sleep 15` file. Prints the share
of the thread's samples whose leaf is memset, by the first pednav / candle frames
above it."""
import collections
import re
import subprocess
import sys

text = subprocess.run(['perf', 'script', '-i', sys.argv[1]], capture_output=True, text=True).stdout


def frames(block):
    out = []
    for line in block.split('\n')[1:]:
        parts = line.strip().split(None, 1)
        if len(parts) == 2:
            out.append(re.sub(r'\+0x[0-9a-f]+$', '', re.sub(r' \(.*\)$', '', parts[1]).strip()))
    return out


total, by = 0, collections.Counter()
for block in text.split('\n\n'):
    f = frames(block)
    if not f:
        continue
    total += 1
    if 'memset' in f[0]:
        callers = [x for x in f[1:12] if 'pednav' in x or 'candle' in x][:2]
        by[' <- '.join(c[:100] for c in callers)] += 1
print(f'{sys.argv[1]}: {total} samples of the thread; memset leaves by caller:')
for k, n in by.most_common(10):
    print(f'{100 * n / total:5.1f}%  {k}')
