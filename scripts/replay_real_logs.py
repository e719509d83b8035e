#!/usr/bin/env python3
"""The controller over real robots' logs (issue 27's log target), measured with `dvnav replay`.

For each bag and each goal, `dvnav replay BAG --goal X,Y --out CSV` answers every recorded scan
as `dvnav serve` would have, given the recorded odometry; this script places the goals around
the robot's first recorded pose (3 m ahead, left, right and behind it by default) and adds up,
over the cycles before the goal is reached:

- **toward**: the share of cycles whose command heads for the goal: turning towards its side
  (ω · bearing > 0), or driving forwards (v > 0.05 m/s) while it is in front (|bearing| < 90°);
  a goal within 30° of straight behind counts any turn of |ω| > 0.3 rad/s (either way is towards
  it). `deploy/ros2/tests/test_replay.py` holds a synthesized log to the same rule.
- **mean |Δω|**: the mean change of the commanded ω between consecutive scans (rad/s per cycle).
- **the recorded driver's mean |Δω|**: the same for the odometry's ω, for scale: a goal's bearing
  turns with the recorded robot, and the commands follow it.
- **into returns**: the share of cycles whose command, held for 1 s with the world standing
  still, drives the disc covering the robot into one of the scan's returns (`dvnav replay`'s
  `arc_clearance_m` < 0), beside the same for the recorded driver's velocity. This one tests
  what the controller makes of its scan: heading for the goal alone would not keep it low.
- **filled**: the mean number of the meta agent's 540 beams no valid reading reached.

The recorded robot was driven by its own controller, not this one, so the scans are what the
robot saw along its own path: this measures what the controller would command at each of those
moments, not where it would have gone.

    python3 scripts/replay_real_logs.py --dvnav target/release/dvnav BAG [BAG ...] --json out.json

Bags are rosbag2 directories or files (`.db3`, `.mcap`); docs/results.md names the public ones
measured and where they come from.
"""

import argparse
import csv
import json
import math
import os
import subprocess
import sys
import tempfile


def run_replay(dvnav, bag, goal, out, extra):
    cmd = [dvnav, "replay", bag, "--goal", f"{goal[0]:.4f},{goal[1]:.4f}", "--out", out, *extra]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"replay_real_logs: `{' '.join(cmd)}` failed ({r.returncode}):\n{r.stderr}")
    with open(out, newline="") as f:
        return list(csv.DictReader(f)), r.stderr


def toward(row):
    v, w, a = float(row["v"]), float(row["omega"]), float(row["goal_angle"])
    if abs(a) > math.radians(150):
        return abs(w) > 0.3
    return (v > 0.05 and math.cos(a) > 0) or w * a > 0


def measure(rows):
    rows = [r for r in rows if r["arrived"] == "false"]
    if len(rows) < 2:
        return None
    omegas = [float(r["omega"]) for r in rows]
    recorded = [float(r["odom_omega"]) for r in rows]

    def into(key):
        # Cycles whose velocity, held for a second, drives the robot's disc into a return.
        known = [float(r[key]) for r in rows if r[key] != ""]
        return sum(c < 0 for c in known) / max(len(known), 1)

    return {
        "into_returns": into("arc_clearance_m"),
        "recorded_into_returns": into("recorded_arc_clearance_m"),
        "cycles": len(rows),
        "toward": sum(map(toward, rows)) / len(rows),
        "mean_abs_domega": sum(abs(b - a) for a, b in zip(omegas, omegas[1:])) / (len(omegas) - 1),
        "recorded_mean_abs_domega": sum(abs(b - a) for a, b in zip(recorded, recorded[1:])) / (len(rows) - 1),
        "filled_beams_mean": sum(int(r["filled_beams"]) for r in rows) / len(rows),
    }


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("bags", nargs="+", help="rosbag2 directories or files")
    p.add_argument("--dvnav", default="target/release/dvnav")
    p.add_argument("--distance", type=float, default=3.0, help="goal distance from the first pose (m)")
    p.add_argument(
        "--bearings",
        default="0,90,-90,180",
        help="goal bearings from the first pose's heading (degrees, left positive)",
    )
    p.add_argument("--json", help="write every figure here")
    p.epilog = "Arguments after `--` go to every `dvnav replay` (e.g. `-- --footprint FILE`)."
    argv = sys.argv[1:]
    extra = argv[argv.index("--") + 1 :] if "--" in argv else []
    a = p.parse_args(argv[: len(argv) - len(extra) - (1 if "--" in argv else 0)])
    bearings = [float(b) for b in a.bearings.split(",")]
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "c.csv")
        for bag in a.bags:
            # The first recorded pose, from a replay towards any goal.
            rows, log = run_replay(a.dvnav, bag, (0.0, 0.0), out, extra)
            x0, y0, yaw0 = (float(rows[0][k]) for k in ("x", "y", "yaw"))
            notes = [line for line in log.splitlines() if line.startswith("replay: ") and "wrote" not in line]
            for b in bearings:
                h = yaw0 + math.radians(b)
                goal = (x0 + a.distance * math.cos(h), y0 + a.distance * math.sin(h))
                rows, _ = run_replay(a.dvnav, bag, goal, out, extra)
                m = measure(rows)
                if m is None:
                    continue
                results.append({"bag": bag, "bearing_deg": b, "goal": goal, **m})
                print(
                    f"{bag}: goal {a.distance:g} m at {b:+.0f}°: toward on {100 * m['toward']:.1f} % of "
                    f"{m['cycles']} cycles, mean |Δω| {m['mean_abs_domega']:.3f} rad/s (recorded "
                    f"{m['recorded_mean_abs_domega']:.3f}), into returns {100 * m['into_returns']:.1f} % "
                    f"(recorded {100 * m['recorded_into_returns']:.1f} %), "
                    f"{m['filled_beams_mean']:.1f} beams filled"
                )
            for n in notes:
                print(f"  {n}")
    cycles = sum(r["cycles"] for r in results)
    pooled = {
        "cycles": cycles,
        "toward": sum(r["toward"] * r["cycles"] for r in results) / cycles,
        "mean_abs_domega": sum(r["mean_abs_domega"] * r["cycles"] for r in results) / cycles,
        "recorded_mean_abs_domega": sum(r["recorded_mean_abs_domega"] * r["cycles"] for r in results) / cycles,
        "into_returns": sum(r["into_returns"] * r["cycles"] for r in results) / cycles,
        "recorded_into_returns": sum(r["recorded_into_returns"] * r["cycles"] for r in results) / cycles,
        "worst_toward": min(r["toward"] for r in results),
        "worst_mean_abs_domega": max(r["mean_abs_domega"] for r in results),
    }
    print(
        f"pooled over {len(results)} bag-goal pairs, {cycles} cycles: toward on {100 * pooled['toward']:.1f} % "
        f"(worst {100 * pooled['worst_toward']:.1f} %), mean |Δω| {pooled['mean_abs_domega']:.3f} rad/s "
        f"(worst {pooled['worst_mean_abs_domega']:.3f}; the recorded driver's {pooled['recorded_mean_abs_domega']:.3f}), "
        f"into returns on {100 * pooled['into_returns']:.1f} % (the recorded driver's {100 * pooled['recorded_into_returns']:.1f} %)"
    )
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"pooled": pooled, "runs": results, "replay_args": extra}, f, indent=1)


if __name__ == "__main__":
    main()
