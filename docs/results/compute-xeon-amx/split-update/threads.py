import sys,collections,subprocess
# Per-thread busy share and top symbols of a `perf record -F 99 -p PID -- sleep 30` file.
f=sys.argv[1]
out=subprocess.run(['perf','script','-i',f,'-F','tid,ip,sym'],capture_output=True,text=True).stdout
c=collections.Counter(); t=collections.Counter()
for line in out.splitlines():
    p=line.split(None,2)
    if len(p)<2: continue
    tid,sym=p[0],(p[2] if len(p)>2 else '[unknown]').strip().split('::{{')[0][:80]
    c[(tid,sym)]+=1; t[tid]+=1
tot=sum(t.values())
print(f'{f}: {tot} samples at 99 Hz over 30 s (a thread busy all the time: ≈ 2,970)')
for tid,n in t.most_common():
    print(f'thread {tid}: {n} samples ({n/2970:.0%} busy, {n/tot:.1%} of the samples)')
    for (a,s),k in sorted(((k,v) for k,v in c.items() if k[0]==tid), key=lambda kv:-kv[1])[:20]:
        print(f'   {100*k/n:5.1f}%  {s}')
