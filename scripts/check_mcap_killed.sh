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
# Wait for actor-0 to have rotated a few files (3 episodes each), then kill it mid-episode.
for _ in $(seq 1 600); do
  [ "$(ls "$run/mcap/actor-0" 2>/dev/null | wc -l)" -ge 6 ] && break
  sleep 0.1
done
pid=$("$python" -c 'import json,sys; print(json.load(open(sys.argv[1]))["actors"][0]["pid"])' "$run/pids.json")
kill -KILL "$pid"
echo "check-mcap: killed actor-0 (pid $pid) mid-run"
wait "$train"
"$python" scripts/check_mcap.py --expect-killed "$run"
