#!/usr/bin/env python3
"""Attributes symprof's per-address counts to source functions, innermost inlined frame
first (addr2line -i): `attribute.py ELF COUNTS [--depth N] [--top K] [--own PREFIX]`
(--own: start at the innermost frame whose name contains PREFIX, e.g. `strata`, so that
inlined library helpers count with the function that used them)."""
import subprocess, sys, collections, argparse
ap = argparse.ArgumentParser()
ap.add_argument("elf"); ap.add_argument("pcs")
ap.add_argument("--depth", type=int, default=1, help="inline frames to show, innermost first")
ap.add_argument("--top", type=int, default=40)
ap.add_argument("--own", default=None, help="skip inner frames until one contains this")
ap.add_argument("--lines", default=None, help="source lines (innermost frame) of functions containing this")
a = ap.parse_args()
rows = [l.split() for l in open(a.pcs)]
addrs = [r[0] for r in rows]
counts = [int(r[1]) for r in rows]
out = subprocess.run(["llvm-addr2line", "-e", a.elf, "-f", "-i", "-C", "-a"] + addrs, capture_output=True, text=True).stdout.splitlines()
# Output: address line, then (function, file:line) pairs per inline frame.
frames, cur = [], None
for line in out:
    if line.startswith("0x"):
        cur = []; frames.append(cur)
    else:
        cur.append(line)
agg = collections.Counter()
total = sum(counts)
for f, c in zip(frames, counts):
    fns = [f[i] for i in range(0, len(f), 2)]
    fns = [x.split("::h")[0] if "::h" in x else x for x in fns]
    if a.own:
        own = [i for i, x in enumerate(fns) if a.own in x]
        fns = fns[own[0]:] if own else fns
    key = " <- ".join(fns[:a.depth])
    if a.lines is not None:
        locs = [f[i + 1] for i in range(0, len(f), 2)]
        own = [i for i, x in enumerate(fns) if a.lines in x]
        if not own:
            continue
        key = f"{fns[own[0]].split('::')[-1]} {locs[0].split('/')[-1]} ({fns[0][-40:]})"
    agg[key] += c
print(f"total {total}")
for k, c in agg.most_common(a.top):
    print(f"{c:14d} {100*c/total:6.2f}% {k}")
