#!/usr/bin/env bash
# The multi-host test (issue 8): a learner and two actors in three Linux network namespaces
# joined by veth links, training over real (non-loopback) addresses, as a run across machines
# would: over TLS (certificates from `dvnav certs` for the learner's addresses) with a shared
# token. Mid-run the link to actor-1 is cut for CUT_S seconds and restored; the run must carry
# on and finish with every transition an actor sent received exactly once, and actor-1 must
# deliver after the cut (reconnecting over TLS).
#
#   sudo scripts/multihost.sh [path/to/dvnav]      (needs root: ip netns)
#
# Exits 0 with "SKIPPED" when network namespaces cannot be made here.
set -euo pipefail
DVNAV=$(realpath "${1:-target/debug/dvnav}")
CUT_S=${CUT_S:-20}
OUT=$(mktemp -d /tmp/dvnav-multihost.XXXXXX)
NS=(dvmh-l dvmh-a0 dvmh-a1)
PIDS=()

cleanup() {
    for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null || true; done
    for n in "${NS[@]}"; do ip netns del "$n" 2>/dev/null || true; done
}
trap cleanup EXIT

if ! ip netns add dvmh-probe 2>/dev/null; then
    echo "multihost: SKIPPED: cannot create network namespaces here (not root, or no CAP_NET_ADMIN)"
    exit 0
fi
ip netns del dvmh-probe
for n in "${NS[@]}"; do ip netns del "$n" 2>/dev/null || true; ip netns add "$n"; ip -n "$n" link set lo up; done
# learner 10.77.1.1 <-> actor-0 10.77.1.2, learner 10.77.2.1 <-> actor-1 10.77.2.2
for i in 0 1; do
    ip link add "dvmh-l$i" netns dvmh-l type veth peer name "dvmh-a$i" netns "dvmh-a$i"
    ip -n dvmh-l addr add "10.77.$((i + 1)).1/24" dev "dvmh-l$i"
    ip -n "dvmh-a$i" addr add "10.77.$((i + 1)).2/24" dev "dvmh-a$i"
    ip -n dvmh-l link set "dvmh-l$i" up
    ip -n "dvmh-a$i" link set "dvmh-a$i" up
done

cat > "$OUT/config.toml" <<'TOML'
[run]
steps = 60000
seed = 5
[sac]
batch_size = 32
learning_starts = 500
updates_per_env_step = 0.05
[learner]
publish_every_updates = 10
checkpoint_every_updates = 1000
max_steps_ahead = 1000
eval_every_updates = 0
[actor]
envs = 2
batch_transitions = 64
[warmup]
pid_episodes = 10
[logging]
every_nth_episode = 0
TOML

# The learner's certificate names both addresses it is reached at; actors trust the CA.
"$DVNAV" certs --out "$OUT/certs" --host 10.77.1.1 --host 10.77.2.1 >/dev/null
head -c 32 /dev/urandom | base64 >"$OUT/token"

export CANDLE_NUM_THREADS=1 RAYON_NUM_THREADS=1
ip netns exec dvmh-l "$DVNAV" learner --config "$OUT/config.toml" --out "$OUT/run" \
    --listen 0.0.0.0:50051 --tls-cert "$OUT/certs/server.pem" --tls-key "$OUT/certs/server.key" \
    --token-file "$OUT/token" >"$OUT/learner.log" 2>&1 &
LEARNER=$!
PIDS+=("$LEARNER")
sleep 1
for i in 0 1; do
    ip netns exec "dvmh-a$i" "$DVNAV" actor --learner "https://10.77.$((i + 1)).1:50051" \
        --tls-ca "$OUT/certs/ca.pem" --token-file "$OUT/token" \
        --name "actor-$i" --out "$OUT/run" >"$OUT/actor-$i.log" 2>&1 &
    PIDS+=("$!")
done

# Cut actor-1's link once the run is under way, then restore it.
for _ in $(seq 1 120); do
    [ -s "$OUT/run/metrics.csv" ] && [ "$(wc -l <"$OUT/run/metrics.csv")" -ge 4 ] && break
    sleep 0.5
done
echo "multihost: cutting the link to actor-1 for ${CUT_S} s"
ip -n dvmh-l link set dvmh-l1 down
sleep "$CUT_S"
ip -n dvmh-l link set dvmh-l1 up
echo "multihost: link restored"
CUT_END=$(date +%s)
if ! kill -0 "$LEARNER" 2>/dev/null; then
    # An actor cut off while the run ended never hears "stop" and (by design) keeps trying.
    echo "multihost: FAILED: the run ended during the cut; raise [run] steps so it outlives it"
    exit 1
fi

wait "$LEARNER"
# Actors leave once told to stop; one that does not within a minute is a failure, not a hang.
for p in "${PIDS[@]:1}"; do
    for _ in $(seq 1 120); do kill -0 "$p" 2>/dev/null || break; sleep 0.5; done
    if kill -0 "$p" 2>/dev/null; then
        echo "multihost: FAILED: an actor did not stop within 60 s of the learner"
        tail -5 "$OUT"/actor-*.log
        exit 1
    fi
    wait "$p" || { echo "multihost: an actor failed"; tail -20 "$OUT"/actor-*.log; exit 1; }
done

python3 - "$OUT" "$CUT_END" <<'PY'
import json, sys, os
out, cut_end = sys.argv[1], int(sys.argv[2])
run = os.path.join(out, "run")
learner = json.load(open(os.path.join(run, "learner_summary.json")))
by_name = {a["name"]: a for a in learner["actors"]}
ok = True
for name in ("actor-0", "actor-1"):
    s = json.load(open(os.path.join(run, "actors", name, "summary.json")))
    sent, got = s["transitions_sent"], by_name[name]["transitions_received"]
    print(f"multihost: {name}: sent {sent}, received {got}, rejected {by_name[name]['transitions_rejected']}")
    ok &= sent == got and by_name[name]["transitions_rejected"] == 0
llog = open(os.path.join(out, "learner.log")).read()
secured = "tls=true" in llog and "token=true" in llog
print(f"multihost: the learner served TLS with a token: {secured}")
ok &= secured
log = open(os.path.join(out, "actor-1.log")).read()
reconnected = "reconnect" in log.lower()
print(f"multihost: actor-1 saw the cut and reconnected: {reconnected}")
ok &= reconnected and learner["transitions_received"] >= learner["step_budget"]
print("multihost: OK" if ok else "multihost: FAILED")
sys.exit(0 if ok else 1)
PY
