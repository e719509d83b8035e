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
trap 'rm -f "$config"' EXIT
# Long enough that the kill falls well inside the run.
sed 's/^steps = 2000/steps = 6000/' scripts/check_mcap.toml > "$config"
"$dvnav" train --actors 2 --config "$config" --out "$run" --progress-every-s 60 &
train=$!
# Wait for actor-0 to have rotated a few files (3 episodes each) and for one of its open files
# (the newest of an environment) to hold a complete episode: a file gets its first bytes when
# its first episode's chunk is written whole. Then kill it, mid-episode. Killing the moment a
# file appears would catch the new files empty, with nothing in them to check.
ready() {
  "$python" - "$run/mcap/actor-0" <<'PY'
import os, sys
d = sys.argv[1]
try:
    files = sorted(f for f in os.listdir(d) if f.endswith(".mcap"))
except FileNotFoundError:
    sys.exit(1)
newest = {f.rsplit("-", 1)[0]: f for f in files}
ok = len(files) >= 6 and any(os.path.getsize(os.path.join(d, f)) > 0 for f in newest.values())
sys.exit(0 if ok else 1)
PY
}
for _ in $(seq 1 600); do
  ready && break
  sleep 0.05
done
pid=$("$python" -c 'import json,sys; print(json.load(open(sys.argv[1]))["actors"][0]["pid"])' "$run/pids.json")
kill -KILL "$pid"
echo "check-mcap: killed actor-0 (pid $pid) mid-run"
wait "$train"
"$python" scripts/check_mcap.py --expect-killed "$run"
