#!/usr/bin/env python3
"""Import cycles between the solver crate's modules.

Usage: python3 scripts/module_cycles.py [SRC]   (default crates/pmpm/src)

A module is a top-level file or directory of SRC (pressure/assemble.rs counts as `pressure`).
An edge A -> B is a `crate::B` path anywhere in A's files outside `#[cfg(test)]` blocks (doc
links included: a doc link to B is a dependency for a reader). Prints every strongly
connected set of more than one module, then each module's edges, and the modules that name
`crate::deck`. Exit status 1 when there is a cycle.
"""
import collections
import os
import re
import sys

src = sys.argv[1] if len(sys.argv) > 1 else "crates/pmpm/src"
edges = collections.defaultdict(set)
for root, _, files in os.walk(src):
    for f in files:
        if not f.endswith(".rs"):
            continue
        path = os.path.relpath(os.path.join(root, f), src)
        parts = path[:-3].split(os.sep)
        module = parts[0]
        if module in ("lib", "main"):
            continue
        text = open(os.path.join(root, f)).read().split("#[cfg(test)]")[0]
        for target in re.findall(r"crate::([a-z_]+)", text):
            is_module = os.path.exists(os.path.join(src, target + ".rs")) or os.path.isdir(
                os.path.join(src, target)
            )
            if is_module and target != module:
                edges[module].add(target)
        edges.setdefault(module, set())

index, low, stack, on, sccs, counter = {}, {}, [], set(), [], [0]


def connect(v):
    index[v] = low[v] = counter[0]
    counter[0] += 1
    stack.append(v)
    on.add(v)
    for w in sorted(edges[v]):
        if w not in index:
            connect(w)
            low[v] = min(low[v], low[w])
        elif w in on:
            low[v] = min(low[v], index[w])
    if low[v] == index[v]:
        component = []
        while True:
            w = stack.pop()
            on.discard(w)
            component.append(w)
            if w == v:
                break
        sccs.append(sorted(component))


for v in sorted(edges):
    if v not in index:
        connect(v)
cycles = [c for c in sccs if len(c) > 1]
for c in cycles:
    print("cycle:", " ".join(c))
for m in sorted(edges):
    print(f"{m} -> {' '.join(sorted(edges[m]))}")
print("name crate::deck:", " ".join(m for m in sorted(edges) if "deck" in edges[m]))
sys.exit(1 if cycles else 0)
