#!/usr/bin/env bash
# `make check-mcap`, the killed-actor part: a `dvnav train` run that logs every episode, whose
# actor-0 is SIGKILLed once it has finished a few files (the supervisor restarts it as
# actor-0-r1). Then scripts/check_mcap.py --expect-killed reads the run: every finished file
# whole, and actor-0's unfinished files as a stream, every complete episode in them decoded by
# the PyPI `mcap` reader. Usage: check_mcap_killed.sh DVNAV PYTHON RUN_DIR
set -euo pipefail
dvnav=$1 python=$2 run=$3
rm -rf "$run"
config=$(mktemp)
train=
# A failed wait below must not leave the run going.
trap 'rm -f "$config"; [ -z "$train" ] || kill "$train" 2> /dev/null || true' EXIT
# Long enough that the kill falls well inside the run.
sed 's/^steps = 2000/steps = 6000/' scripts/check_mcap.toml > "$config"
"$dvnav" train --actors 2 --config "$config" --out "$run" --progress-every-s 60 &
train=$!
# Wait for actor-0 to have rotated a few files (3 episodes each) and for one of its open files
# (the newest of an environment) to hold a complete episode: a file gets its first bytes when
# its first episode's chunk is written whole. Then kill it, mid-episode. Killing the moment a
# file appears would catch the new files empty, with nothing in them to check.
# One process looks and kills: with a separate check and kill (two Python starts, ~0.1 s apart)
# both of actor-0's environments could finish their file (3 short episodes take ~0.25 s) and open
# empty ones in between, and a CI run failed so; here the gap is one stat to one kill.
pid=$("$python" - "$run" <<'PY'
import json, os, signal, sys, time
run = sys.argv[1]
d = os.path.join(run, "mcap", "actor-0")
deadline = time.monotonic() + 60
MAGIC = b"\x89MCAP0\r\n"


def holds_an_open_episode_log(path):
    # Bytes on disk, and not yet finished: a finished file (it ends with the magic) may be an
    # environment's newest for a moment after its last episode, before the next file opens, and
    # a kill then leaves that environment nothing unfinished to read (a CI run failed so).
    size = os.path.getsize(path)
    if size == 0:
        return False
    with open(path, "rb") as f:
        f.seek(max(0, size - len(MAGIC)))
        return f.read() != MAGIC


while True:
    if time.monotonic() > deadline:
        sys.exit("check-mcap: actor-0 wrote no complete episode into a rotated file within 60 s")
    try:
        pid = json.load(open(os.path.join(run, "pids.json")))["actors"][0]["pid"]
        files = sorted(f for f in os.listdir(d) if f.endswith(".mcap"))
        newest = {f.rsplit("-", 1)[0]: f for f in files}
        ready = len(files) >= 6 and any(holds_an_open_episode_log(os.path.join(d, f)) for f in newest.values())
    except (FileNotFoundError, ValueError, KeyError, IndexError):
        # Not yet written (or caught mid-write): look again.
        ready = False
    if ready:
        os.kill(pid, signal.SIGKILL)
        print(pid)
        break
    time.sleep(0.02)
PY
)
echo "check-mcap: killed actor-0 (pid $pid) mid-run"
wait "$train"
train=
"$python" scripts/check_mcap.py --expect-killed "$run"
