#!/usr/bin/env python3
"""Tunes the subgoal rule (issue 28) on rooms that are NOT held out: generated rooms at
training-range seeds (below 9000; the held-out suite uses 9000 and above) and the curriculum
rooms are never part of the held-out figures, so the lookahead and the rotation shim are chosen
here, and only then measured on the held-out suite (scripts/heldout_suite.py --tasks long).

For each setting it runs `dvnav eval --tasks long --subgoals planner` over the tuning rooms and
pools success per radius (the commands are printed, so every figure can be re-run by hand).

    python3 scripts/tune_subgoals.py --dvnav target/release/dvnav
"""

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from heldout_suite import pool, run_eval  # noqa: E402


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--checkpoint", default="models/meta-r0.2")
    p.add_argument("--dvnav", default="target/release/dvnav")
    p.add_argument("--kinds", default="clutter,corridors,rooms")
    p.add_argument("--seeds", default="8000:8004", help="tuning generator seeds A:B (below 9000)")
    p.add_argument("--radii", default="0.2,0.4,0.6")
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--lookaheads", default="1.0,1.5,2.0,3.0")
    p.add_argument("--margins", default="",
                   help="instead of the lookaheads: planner margins M (m) to try, each with the default "
                        "lookahead and shim (dvnav eval --planner-margin M)")
    a = p.parse_args()
    lo, hi = (int(x) for x in a.seeds.split(":"))
    if hi > 9000:
        sys.exit("--seeds: seeds 9000 and above are held out; tune below 9000")

    if a.margins:
        settings = [(f"margin {m} m", ["--planner-margin", m]) for m in a.margins.split(",")]
    else:
        settings = [(f"L = {l} m, shim", ["--lookahead", l]) for l in a.lookaheads.split(",")]
        settings += [(f"L = {l} m, no shim", ["--lookahead", l, "--no-rotation-shim"])
                     for l in a.lookaheads.split(",")]
        settings.append(("mapless", ["--subgoals", "none"]))
    print("| setting | radius (m) | episodes | success | collision | timeout | ω reversals |")
    print("|---|---|---|---|---|---|---|")
    for name, extra in settings:
        rows = []
        for kind in a.kinds.split(","):
            args = ["--checkpoint", a.checkpoint, "--scenario", "generated", "--kind", kind, "--seeds", a.seeds,
                    "--radii", a.radii, "--episodes", str(a.episodes), "--tasks", "long"]
            if "--subgoals" not in extra:
                args += ["--subgoals", "planner"]
            rows += run_eval(a.dvnav, args + extra)
        for radius, f in pool(rows).items():
            pct = lambda v: "-" if v is None else f"{100 * v:.1f} %"
            print(f"| {name} | {radius} | {f['episodes']} | {pct(f['success_rate'])} | {pct(f['collision_rate'])} "
                  f"| {pct(f['timeout_rate'])} | {pct(f['reversal_rate'])} |", flush=True)


if __name__ == "__main__":
    main()
