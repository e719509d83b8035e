#!/usr/bin/env python3
"""The soak test (issue 8): `dvnav train --actors 8` against one learner for MINUTES (default
10) on this machine, then a clean stop. Samples the resident memory of every process every
SAMPLE_S seconds; passes when each process's memory is flat after warm-up (growth over the
second half of the run below GROWTH_MIB), every transition an actor sent was received or
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
p.add_argument("--growth-mib", type=float, default=16)
p.add_argument("--replay-capacity", type=int, default=10000)
a = p.parse_args()
out = a.out or tempfile.mkdtemp(prefix="dvnav-soak-")
run = os.path.join(out, "run")
os.makedirs(out, exist_ok=True)


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
train = subprocess.Popen(
    [a.dvnav, "train", "--actors", str(a.actors), "--steps", "1000000000", "--out", run,
     "--config", config, "--progress-every-s", "60"],
    stderr=open(os.path.join(out, "train.log"), "w"),
    env=dict(os.environ, CANDLE_NUM_THREADS="1"),
)
samples = []  # (t, name, rss)
start = time.time()
deadline = start + a.minutes * 60
while time.time() < deadline and train.poll() is None:
    time.sleep(a.sample_s)
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

summary = json.load(open(os.path.join(run, "run_summary.json")))
half = a.minutes * 60 / 2
growth = {}
for name in sorted({n for _, n, _ in samples}):
    late = [(t, r) for t, n, r in samples if n == name and t >= half]
    if len(late) >= 2:
        growth[name] = round(late[-1][1] - late[0][1], 1)
peak = {n: round(max(r for _, m, r in samples if m == n), 1) for n in growth}
errors = []
for log in os.listdir(os.path.join(run, "logs")):
    for line in open(os.path.join(run, "logs", log), errors="replace"):
        if " ERROR " in line:
            errors.append(f"{log}: {line.strip()[:200]}")
sent = summary["transitions_sent"]
received, rejected = summary["transitions_received"], summary["transitions_rejected"]
ok = (
    not crashed
    and code == 0
    and summary["clean_shutdown"]
    and sent == received + rejected
    and all(abs(g) < a.growth_mib for g in growth.values())
    and not errors
)
print(json.dumps({
    "ok": ok, "minutes": a.minutes, "actors": a.actors, "exit_code": code,
    "transitions_sent": sent, "transitions_received": received, "transitions_rejected": rejected,
    "env_steps_per_s": summary.get("env_steps_per_s"), "updates": summary.get("updates"),
    "rss_growth_second_half_mib": growth, "rss_peak_mib": peak, "error_lines": errors[:10],
    "out": out,
}, indent=1))
sys.exit(0 if ok else 1)
