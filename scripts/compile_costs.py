#!/usr/bin/env python3
"""What a cold start compiles, kernel by kernel: the figures of docs/PERFORMANCE.md
("Cold start") that ``cdf-mj bench``'s one cold-start row does not break down::

    taskset -c 0 python scripts/compile_costs.py             # a cdf episode, labels included
    python scripts/compile_costs.py --planner imm-layered

Runs ``cdf-mj episode --planner PLANNER --seed 0`` in a fresh interpreter with an empty
``NUMBA_CACHE_DIR`` and Numba's compile events recorded, then prints the CPU seconds of
the whole process, of the imports, and every compiled function's own compile time (its
callees' left out) with how many times it compiled, largest first. Bad arguments are one
line ``compile_costs: error: ...`` and exit status 2; a failed child, exit status 1.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

# Runs in the child: compile listeners around the CLI's episode command.
_CHILD = r"""
import contextlib, io, json, sys, time
t0 = time.process_time()
from numba.core import event
stack, own = [], {}

class Compiles(event.Listener):
    def on_start(self, ev):
        f = ev.data["dispatcher"].py_func
        stack.append([f"{f.__module__}.{f.__qualname__}", time.process_time(), 0.0])
    def on_end(self, ev):
        name, start, inner = stack.pop()
        whole = time.process_time() - start
        if stack:
            stack[-1][2] += whole
        n, sec = own.get(name, (0, 0.0))
        own[name] = (n + 1, sec + whole - inner)

event.register("numba:compile", Compiles())
from cdf_mj.cli.app import main
imported = time.process_time() - t0
with contextlib.redirect_stdout(io.StringIO()):
    status = main(["episode", "--planner", sys.argv[1], "--seed", "0"])
print(json.dumps({"status": status, "total": time.process_time() - t0, "imports": imported, "own": own}))
"""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="compile_costs", description=__doc__.split("\n\n")[0])
    parser.add_argument("--planner", default="cdf", help="the episode's planner (default cdf)")
    args = parser.parse_args(argv)
    from cdf_mj.planners.registry import PLANNERS

    if args.planner not in PLANNERS:
        parser.error(f"unknown planner {args.planner!r}; one of {', '.join(sorted(PLANNERS))}")
    with tempfile.TemporaryDirectory(prefix="cdf-mj-numba-") as cache:
        done = subprocess.run([sys.executable, "-c", _CHILD, args.planner], capture_output=True, text=True,
                              env={**os.environ, "NUMBA_CACHE_DIR": cache}, check=False)
    if done.returncode != 0 or not done.stdout.strip():
        print(f"compile_costs: the episode failed: {done.stderr.strip()[-500:]}", file=sys.stderr)
        return 1
    result = json.loads(done.stdout.strip().splitlines()[-1])
    own = result["own"]
    compiled = sum(sec for _, sec in own.values())
    ours = [k for k in own if k.startswith("cdf_mj.")]
    print(f"{args.planner}: {result['total']:.2f} s of CPU, imports {result['imports']:.2f} s, compiling "
          f"{compiled:.2f} s in {len(own)} functions ({len(ours)} of cdf_mj, {len(own) - len(ours)} of Numba's own)\n")
    print("| function | compiles | own seconds |\n|---|---|---|")
    for name, (n, sec) in sorted(own.items(), key=lambda kv: -kv[1][1]):
        print(f"| {name} | {n} | {sec:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
