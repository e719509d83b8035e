#!/usr/bin/env python3
"""The soak test (issue 8): `dvnav train --actors 8` against one learner for MINUTES (default
10) on this machine, then a clean stop. Samples the resident memory of every process every
SAMPLE_S seconds, and the learner's bytes in use (allocated, not freed: `/metrics`); passes
when each process's memory and the learner's bytes in use are flat after warm-up (the floor,
the lowest reading, of the last third of the second half at most GROWTH_MIB above that of its
first third), every transition an actor sent was received or
rejected, the run shut down cleanly, and no log line is an ERROR.

    python3 scripts/soak.py [path/to/dvnav] [--minutes 10] [--actors 8] [--out DIR]

Writes DIR/soak.csv (time, process, rss_mib) and prints a JSON summary.
"""
import argparse, json, os, signal, subprocess, sys, tempfile, time

p = argparse.ArgumentParser()
p.add_argument("dvnav", nargs="?", default="target/release/dvnav")
p.add_argument("--minutes", type=float, default=10)
p.add_argument("--actors", type=int, default=8)
p.add_argument("--out", default=None)
p.add_argument("--sample-s", type=float, default=15)
p.add_argument("--heap-sample-s", type=float, default=1.0,
               help="seconds between readings of the learner's heap in use (RSS: --sample-s)")
p.add_argument("--growth-mib", type=float, default=16)
p.add_argument("--replay-capacity", type=int, default=10000)
p.add_argument("--eval-every-updates", type=int, default=None,
               help="learner.eval_every_updates (default: the config's); smaller shows whether "
                    "each evaluation adds memory or only the first")
a = p.parse_args()
out = a.out or tempfile.mkdtemp(prefix="dvnav-soak-")
run = os.path.join(out, "run")
os.makedirs(out, exist_ok=True)


def heap_in_use_mib():
    """The learner's bytes allocated and not freed (`dvnav_heap_in_use_bytes` in /metrics)."""
    import urllib.request
    try:
        addr = open(os.path.join(run, "metrics.addr")).read().strip()
        text = urllib.request.urlopen(f"http://{addr}/metrics", timeout=5).read().decode()
    except (OSError, ValueError):
        return None
    for line in text.splitlines():
        if line.startswith("dvnav_heap_in_use_bytes "):
            return float(line.split()[1]) / 2**20
    return None


def rss_mib(pid):
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        return None


# A replay buffer that is full after warm-up (the default 5e5 would legitimately grow for
# hours), so that any growth after it is a leak; everything else is the default config.
config = os.path.join(out, "soak.toml")
with open(config, "w") as f:
    f.write("[replay]\ncapacity = %d\n" % a.replay_capacity)
    if a.eval_every_updates is not None:
        f.write("[learner]\neval_every_updates = %d\n" % a.eval_every_updates)
train = subprocess.Popen(
    [a.dvnav, "train", "--actors", str(a.actors), "--steps", "1000000000", "--out", run,
     "--config", config, "--progress-every-s", "60", "--metrics-addr", "127.0.0.1:0"],
    stderr=open(os.path.join(out, "train.log"), "w"),
    env=dict(os.environ, CANDLE_NUM_THREADS="1"),
)
samples = []  # (t, name, rss)
heap = []  # (t, learner heap in use MiB)
start = time.time()
deadline = start + a.minutes * 60
next_rss = start + a.sample_s
while time.time() < deadline and train.poll() is None:
    # The heap swings by tens of MiB with the update in flight, so its floor needs many
    # readings: one a second (a 15-s cadence once failed a flat run on 7 readings a third).
    time.sleep(a.heap_sample_s)
    h = heap_in_use_mib()
    if h is not None:
        heap.append((time.time() - start, h))
    if time.time() < next_rss:
        continue
    next_rss += a.sample_s
    try:
        pids = json.load(open(os.path.join(run, "pids.json")))
    except (OSError, ValueError):
        continue
    procs = [("learner", pids["learner"])] + [(x["process"], x["pid"]) for x in pids["actors"]]
    t = time.time() - start
    for name, pid in procs:
        r = rss_mib(pid)
        if r is not None:
            samples.append((t, name, r))
    print(f"soak: {t:5.0f} s " + " ".join(f"{n}={r:.0f}" for tt, n, r in samples if tt == t),
          flush=True)
crashed = train.poll() is not None
train.send_signal(signal.SIGINT)
code = train.wait(timeout=180)
with open(os.path.join(out, "soak.csv"), "w") as f:
    f.write("time_s,process,rss_mib\n")
    for t, n, r in samples:
        f.write(f"{t:.1f},{n},{r:.1f}\n")
    for t, h in heap:
        f.write(f"{t:.1f},learner-heap-in-use,{h:.1f}\n")

summary = json.load(open(os.path.join(run, "run_summary.json")))
half = a.minutes * 60 / 2


def floor_growth(points):
    """Growth of the floor over the second half: the lowest reading of its last third less
    the lowest of its first third. A leak raises the floor; the learner's memory swings by
    tens of MiB with the update in flight at the moment of a reading (candle's temporaries),
    which a last-less-first difference would count."""
    late = [(t, v) for t, v in points if t >= half]
    if len(late) < 6:
        return None
    third = len(late) // 3
    return round(min(v for _, v in late[-third:]) - min(v for _, v in late[:third]), 1)


growth, raw_growth = {}, {}
for name in sorted({n for _, n, _ in samples}):
    points = [(t, r) for t, n, r in samples if n == name]
    late = [r for t, r in points if t >= half]
    if len(late) >= 2:
        raw_growth[name] = round(late[-1] - late[0], 1)
    g = floor_growth(points)
    if g is not None:
        growth[name] = g
peak = {n: round(max(r for _, m, r in samples if m == n), 1) for n in growth}
late_heap = [h for t, h in heap if t >= half]
heap_growth = floor_growth(heap)
errors, stalls = [], []
for log in os.listdir(os.path.join(run, "logs")):
    for line in open(os.path.join(run, "logs", log), errors="replace"):
        if " ERROR " in line:
            errors.append(f"{log}: {line.strip()[:200]}")
        if "watchdog: component stalled" in line:
            stalls.append(f"{log}: {line.strip()[:200]}")
# Evaluations during the run, and the learner's memory right after each one: flat from one
# evaluation to the next is an allocator's high-water mark, a rise at every one a leak.
evals = []
try:
    rows = open(os.path.join(run, "eval.csv")).read().splitlines()[1:]
    evals = sorted({int(r.split(",")[0]) for r in rows if r})
except OSError:
    pass
sent = summary["transitions_sent"]
received, rejected = summary["transitions_received"], summary["transitions_rejected"]
ok = (
    not crashed
    and code == 0
    and summary["clean_shutdown"]
    and sent == received + rejected
    and all(abs(g) < a.growth_mib for g in growth.values())
    and (heap_growth is None or abs(heap_growth) < a.growth_mib)
    and not errors
)
print(json.dumps({
    "ok": ok, "minutes": a.minutes, "actors": a.actors, "exit_code": code,
    "transitions_sent": sent, "transitions_received": received, "transitions_rejected": rejected,
    "env_steps_per_s": summary.get("env_steps_per_s"), "updates": summary.get("updates"),
    "rss_floor_growth_second_half_mib": growth, "rss_last_less_first_second_half_mib": raw_growth, "rss_peak_mib": peak, "error_lines": errors[:10],
    "learner_heap_in_use_mib_second_half": [round(min(late_heap), 1), round(max(late_heap), 1)]
    if late_heap else None,
    "learner_heap_in_use_floor_growth_second_half_mib": heap_growth,
    "evaluations_at_updates": evals, "watchdog_stall_lines": len(stalls),
    "watchdog_stalls": stalls[:10],
    "out": out,
}, indent=1))
sys.exit(0 if ok else 1)
