#!/usr/bin/env python3
"""The PassFirstTask statistic over first-task episodes (standard library only).

For each results.csv given (one pednav-eval run of the first task, one row per
episode), prints the mean return, the success share, and the best mean of 30
consecutive episodes in two orders:
  - sequential: the episodes in the order they were run;
  - parallel:   as the curriculum service sees them in a run, where 8 environments
                play episodes side by side and the fast ones report first. Each of
                20 seeded shuffles of the episodes is dealt to 8 environments and the
                reports ordered by completion time (episode lengths in steps).
Usage: window_stats.py DIR [DIR ...]   (each DIR holds a results.csv)
"""
import csv
import heapq
import random
import statistics
import sys

WINDOW, ENVS, SHUFFLES = 30, 8, 20


def best_window(returns):
    sums = [sum(returns[i:i + WINDOW]) / WINDOW for i in range(len(returns) - WINDOW + 1)]
    return max(sums)


def completion_order(episodes, rng):
    seq = episodes[:]
    rng.shuffle(seq)
    it = iter(seq)
    heap = []
    for env in range(ENVS):
        ret, steps = next(it)
        heapq.heappush(heap, (steps, env, ret))
    done = []
    while heap:
        t, env, ret = heapq.heappop(heap)
        done.append(ret)
        nxt = next(it, None)
        if nxt is not None:
            heapq.heappush(heap, (t + nxt[1], env, nxt[0]))
    return done


for folder in sys.argv[1:]:
    rows = list(csv.DictReader(open(f"{folder}/results.csv")))
    episodes = [(float(r["discounted_return"]), int(r["steps"])) for r in rows]
    returns = [e[0] for e in episodes]
    success = sum(r["success"] == "true" for r in rows) / len(rows)
    parallel = max(best_window(completion_order(episodes, random.Random(k))) for k in range(SHUFFLES))
    print(f"{folder}: {len(rows)} episodes, mean {statistics.mean(returns):7.1f}, success {success:4.0%}, "
          f"best 30-window sequential {best_window(returns):7.1f}, parallel {parallel:7.1f}")
