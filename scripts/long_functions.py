#!/usr/bin/env python3
"""Functions longer than a limit, outside test modules.

Usage: python3 scripts/long_functions.py [LIMIT]   (default 120 lines)

Reads the solver crate (crates/pmpm/src) and the application (src). A function runs from its
`fn` line to the closing brace at the same indentation; everything from a file's first
`#[cfg(test)]` on is skipped. Prints `lines file name line` for each one over the limit,
longest first, and exits with status 1 when there is one.
"""
import os
import re
import sys

limit = int(sys.argv[1]) if len(sys.argv) > 1 else 120
found = []
for top in ["crates/pmpm/src", "src"]:
    for root, _, files in os.walk(top):
        for f in files:
            if not f.endswith(".rs"):
                continue
            path = os.path.join(root, f)
            lines = open(path).read().split("\n")
            end = next(
                (i for i, l in enumerate(lines) if l.startswith("#[cfg(test)]")), len(lines)
            )
            i = 0
            while i < end:
                m = re.match(r"^(\s*)(pub(\([a-z]+\))?\s+)?(const\s+)?fn\s+(\w+)", lines[i])
                if not m:
                    i += 1
                    continue
                indent = len(m.group(1))
                j = i
                while "{" not in lines[j] and not lines[j].rstrip().endswith(";"):
                    j += 1
                if lines[j].rstrip().endswith(";"):
                    i = j + 1
                    continue
                k = j + 1
                while k < end and not (
                    lines[k].startswith(" " * indent + "}")
                    and len(lines[k]) - len(lines[k].lstrip()) == indent
                ):
                    k += 1
                if k - i + 1 > limit:
                    found.append((k - i + 1, path, m.group(5), i + 1))
                i = k + 1
for n, path, name, line in sorted(found, reverse=True):
    print(n, path, name, line)
sys.exit(1 if found else 0)
