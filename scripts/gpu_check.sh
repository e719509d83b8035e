#!/usr/bin/env bash
# `make gpu-check`: the learner on an NVIDIA GPU, measured. On a machine with a GPU:
#   1. the GPU (nvidia-smi: name, driver, compute capability);
#   2. a dvnav built with `--features cuda`: `--bin PATH` (or $DVNAV_CUDA_BIN) uses one built
#      elsewhere (a GPU machine with no Rust or no network: `make gpu-bin` on any machine
#      writes a stripped one to target/gpu/dvnav; bring that along); otherwise it is built
#      here with the toolkit from scripts/cuda_toolkit.sh (PyPI), CUDA_COMPUTE_CAP from
#      nvidia-smi, into target/cuda/ (from scratch: a few minutes on 16 cores, counted in the
#      budget below);
#   3. `dvnav bench learner --device cuda --json` at batch 256 and 128 in fp32 and at 256 in
#      bf16 (BENCH_CELLS), each cell alternated BENCH_ROUNDS times: the update op by op, the
#      update replayed from its CUDA graph (`--cuda-graph`; checked once against op by op,
#      `--check-cuda-graph`), and the same update in PyTorch on the same GPU
#      (scripts/bench_torch.py --device cuda; autocast for bf16) where python3 has a CUDA torch;
#   4. `dvnav train --device cuda --config TRAIN_CONFIG --stop-when-skilled` for at most
#      TRAIN_SECONDS (300 s), fewer when the build ate into the budget; TRAIN_CONFIG defaults to
#      configs/experiments/cuda-graph.toml (the default run with the update captured as a CUDA
#      graph; system.txt gets the learner's "CUDA graph" log lines: captured, or refused and
#      run op by op);
#   5. the figures in $OUT (default runs/gpu-check): summary.json (the headline numbers),
#      bench.jsonl, train.log, eval.csv, metrics.csv, run_summary.json, system.txt, build.log.
#      At most 8 files, flat, so that all of them come back from a borrowed machine.
#
# The whole script stays inside GPU_CHECK_BUDGET_S (510 s) so that it fits one 9-minute call.
# Env: OUT, DVNAV_CUDA_BIN, TRAIN_SECONDS (300), BENCH_UPDATES (500), BENCH_ROUNDS (2),
# BENCH_CELLS ("256:fp32 128:fp32 256:bf16"),
# ACTORS (16 cores: 6),
# GPU_CHECK_RUN (the training run's directory, default runs/gpu-check/train),
# GPU_CHECK_BUDGET_S (510).
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$(pwd)
start=$(date +%s)
elapsed() { echo $(($(date +%s) - start)); }
say() { echo "gpu-check [$(elapsed) s]: $*" >&2; }
die() {
    say "FAILED: $*"
    exit 1
}

bin=${DVNAV_CUDA_BIN:-}
while [ $# -gt 0 ]; do
    case $1 in
        --bin) bin=${2:?--bin needs a path}; shift 2 ;;
        -h | --help) sed -n '2,/^set -euo/p' "$0" | sed '$d'; exit 0 ;;
        *) die "unknown argument $1 (try --help)" ;;
    esac
done

out=${OUT:-runs/gpu-check}
run_dir=${GPU_CHECK_RUN:-runs/gpu-check/train}
budget=${GPU_CHECK_BUDGET_S:-510}
train_max=${TRAIN_SECONDS:-300}
train_config=${TRAIN_CONFIG:-configs/experiments/cuda-graph.toml}
updates=${BENCH_UPDATES:-500}
cores=$(nproc)
actors=${ACTORS:-$(((cores - 4) / 2))}
[ "$actors" -ge 1 ] || actors=1
mkdir -p "$out"
sys="$out/system.txt"
: >"$sys"

# 1. The GPU.
command -v nvidia-smi >/dev/null 2>&1 || die "no nvidia-smi: this is not a machine with an NVIDIA GPU and driver"
nvidia-smi >>"$sys" 2>&1 || die "nvidia-smi failed: $(tail -n 3 "$sys")"
gpu=$(nvidia-smi --query-gpu=name,driver_version,compute_cap,memory.total --format=csv,noheader | head -n 1)
cap=$(nvidia-smi --query-gpu=compute_cap --format=csv,noheader | head -n 1 | tr -d ' .')
say "GPU: $gpu (CUDA_COMPUTE_CAP=$cap), $cores cores, $actors actors"

# 2. The binary.
build_s=null
if [ -z "$bin" ]; then
    command -v cargo >/dev/null 2>&1 \
        || die "no cargo here and no --bin: build one elsewhere with \`make gpu-bin\` and run this with --bin target/gpu/dvnav"
    export CUDA_COMPUTE_CAP=${CUDA_COMPUTE_CAP:-$cap}
    exports=$(scripts/cuda_toolkit.sh) || die "scripts/cuda_toolkit.sh failed"
    eval "$exports"
    say "cargo build --release --features cuda (target/cuda)"
    b0=$(date +%s)
    cargo build --release --features cuda --target-dir target/cuda --bin dvnav >"$out/build.log" 2>&1 \
        || die "the CUDA build failed; the end of $out/build.log:
$(tail -n 40 "$out/build.log")"
    build_s=$(($(date +%s) - b0))
    bin=target/cuda/release/dvnav
    say "built in $build_s s"
fi
[ -x "$bin" ] || die "$bin is not an executable"
case $bin in /*) ;; *) bin="$repo/$bin" ;; esac

# Its CUDA libraries: where this machine has them, when the loader does not find them itself.
add_lib_dirs() {
    local site
    site=$(python3 -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])' 2>/dev/null) || site=
    for d in ${CUDA_ROOT:+"$CUDA_ROOT/lib"} /usr/local/cuda/lib64 /usr/local/cuda/targets/x86_64-linux/lib \
        ${site:+"$site/nvidia/cu13/lib"} /usr/local/nvidia/lib64 /usr/local/nvidia/lib; do
        [ -d "$d" ] && LD_LIBRARY_PATH="${LD_LIBRARY_PATH:+$LD_LIBRARY_PATH:}$d"
    done
    export LD_LIBRARY_PATH
}
if ldd "$bin" 2>&1 | grep 'not found' >/dev/null; then
    add_lib_dirs
fi
{
    echo "== binary: $bin"
    echo "LD_LIBRARY_PATH=${LD_LIBRARY_PATH:-}"
    ldd "$bin" || true
} >>"$sys" 2>&1
ldd "$bin" 2>&1 | grep 'not found' && die "libraries missing for $bin (above; see $sys)"
"$bin" --version >>"$sys" 2>&1 || die "$bin does not start: $(tail -n 3 "$sys")"

# 3. SAC updates/s on the GPU, dvnav and PyTorch alternated cell by cell so that a clock or
# load change hits both alike. Each line of bench.jsonl carries "who".
rounds=${BENCH_ROUNDS:-2}
: >"$out/bench.jsonl"
torch_ok=no
if python3 -c 'import torch, sys; sys.exit(0 if torch.cuda.is_available() else 1)' >>"$sys" 2>&1; then
    torch_ok=yes
else
    say "no CUDA PyTorch in python3: dvnav's figures only"
fi
for round in $(seq "$rounds"); do
    for cell in ${BENCH_CELLS:-256:fp32 128:fp32 256:bf16}; do
        batch=${cell%:*} precision=${cell#*:}
        # dvnav op by op (the default), then replaying its update captured as a CUDA graph
        # (who = dvnav-graph; the first round also checks it against op by op).
        for who in dvnav dvnav-graph; do
            graph=
            if [ "$who" = dvnav-graph ]; then
                graph=--cuda-graph
                [ "$round" = 1 ] && graph="--cuda-graph --check-cuda-graph"
            fi
            say "round $round: bench learner --device cuda --batch $batch --precision $precision $graph"
            "$bin" bench learner --device cuda --batch "$batch" --precision "$precision" --updates "$updates" \
                $graph --json 2>>"$sys" \
                | WHO=$who python3 -c 'import json,os,sys; r=json.load(sys.stdin); r["who"]=os.environ["WHO"]; print(json.dumps(r))' \
                >>"$out/bench.jsonl" || die "bench learner --batch $batch --precision $precision $graph failed: $(tail -n 5 "$sys")"
            tail -n 1 "$out/bench.jsonl" >&2
        done
        if [ "$torch_ok" = yes ]; then
            if python3 scripts/bench_torch.py --device cuda --batch "$batch" --precision "$precision" \
                --updates "$updates" --warmup 20 2>>"$sys" \
                | python3 -c 'import json,sys; r=json.load(sys.stdin); r["who"]="torch"; print(json.dumps(r))' \
                    >>"$out/bench.jsonl"; then
                tail -n 1 "$out/bench.jsonl" >&2
            else
                say "PyTorch bench failed (see $sys)"
            fi
        fi
    done
done

# 4. Training on the GPU, inside what is left of the budget (45 s kept for the shutdown).
left=$((budget - $(elapsed) - 45))
train_s=$((left < train_max ? left : train_max))
train_rc=skipped
if [ "$train_s" -lt 60 ]; then
    say "only $left s left of the $budget s budget: training skipped"
else
    rm -rf "$run_dir"
    mkdir -p "$(dirname "$run_dir")"
    say "train --device cuda --actors $actors --stop-when-skilled, at most $train_s s"
    set +e
    # SIGTERM: dvnav train stops its learner and actors cleanly and writes run_summary.json.
    timeout --signal=TERM --kill-after=40 "$train_s" \
        "$bin" train --device cuda --config "$train_config" --actors "$actors" --stop-when-skilled \
        --progress-every-s 10 --out "$run_dir" >"$out/train.log" 2>&1
    train_rc=$?
    set -e
    say "train exited with $train_rc (124: stopped at $train_s s)"
    for f in eval.csv metrics.csv run_summary.json; do
        [ -f "$run_dir/$f" ] && cp "$run_dir/$f" "$out/$f"
    done
    [ -f "$run_dir/logs/learner.log" ] && {
        echo "== learner.log: CUDA graph lines"
        grep -i "cuda graph" "$run_dir/logs/learner.log" || echo "(none)"
        echo "== learner.log (end)"
        tail -n 40 "$run_dir/logs/learner.log"
    } >>"$sys"
fi

# 5. The headline figures.
command -v python3 >/dev/null 2>&1 || die "no python3 for summary.json; the raw figures are in $out/"
TRAIN_CONFIG_USED=$train_config python3 - "$out" "$gpu" "$build_s" "$train_s" "$train_rc" "$actors" "$(elapsed)" <<'EOF'
import json, os, sys
out, gpu, build_s, train_s, train_rc, actors, total_s = sys.argv[1:]
def load(p):
    try:
        with open(os.path.join(out, p)) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None
import statistics
# Per cell ("256/fp32"): each side's figure in every round and their median.
rows = []
try:
    rows = [json.loads(l) for l in open(os.path.join(out, "bench.jsonl")) if l.strip()]
except (OSError, ValueError):
    pass
bench = {}
for r in rows:
    rate = r.get("torch_sac_updates_per_s") if r.get("who") == "torch" else r.get("sac_updates_per_s")
    cell = bench.setdefault(f'{r["batch"]}/{r.get("precision", "fp32")}', {})
    cell.setdefault(r["who"], []).append(rate)
for cell in bench.values():
    for who in list(cell):
        cell[who + "_median"] = statistics.median(cell[who])
    if "dvnav_median" in cell and "torch_median" in cell:
        cell["ratio_vs_torch"] = cell["dvnav_median"] / cell["torch_median"]
    if "dvnav_median" in cell and "dvnav-graph_median" in cell:
        cell["ratio_graph_vs_eager"] = cell["dvnav-graph_median"] / cell["dvnav_median"]
for r in rows:
    if r.get("who") == "dvnav-graph":
        cell = bench[f'{r["batch"]}/{r.get("precision", "fp32")}']
        cell["cuda_graph"] = r.get("cuda_graph")
        if r.get("cuda_graph_check"):
            cell["cuda_graph_check"] = r["cuda_graph_check"]
inference = {str(r["batch"]): r.get("inference_ms_batch1") for r in rows if r.get("who") == "dvnav"}
run = load("run_summary.json") or {}
def time_at_steps(steps):
    import csv
    try:
        with open(os.path.join(out, "metrics.csv")) as f:
            for row in csv.DictReader(f):
                if float(row["env_steps"]) >= steps:
                    return float(row["time_s"])
    except (OSError, ValueError, KeyError):
        pass
    return run.get("wall_time_s")
skilled = run.get("skilled")
s = {
    "gpu": gpu,
    "build_s": None if build_s == "null" else int(build_s),
    "sac_updates_per_s": bench,
    "inference_ms_batch1": inference,
    "train": {
        "actors": int(actors),
        "limit_s": int(train_s),
        "exit": train_rc,
        "wall_time_s": run.get("wall_time_s"),
        "stage": run.get("stage"),
        "skilled": skilled,
        # The first metrics row (every 2 s) at or past the skilled step count: --stop-when-skilled
        # ends the run soon after, but a run stopped by the budget meanwhile would overstate it.
        "time_to_skill_s": time_at_steps(skilled["env_steps"]) if skilled else None,
        "env_steps_per_s": run.get("env_steps_per_s"),
        "updates_per_s": run.get("updates_per_s"),
        "updates": run.get("updates"),
        "success_rate": run.get("success_rate"),
        "clean_shutdown": run.get("clean_shutdown"),
        "config": os.environ.get("TRAIN_CONFIG_USED"),
    },
    "total_s": int(total_s),
}
with open(os.path.join(out, "summary.json"), "w") as f:
    json.dump(s, f, indent=2)
print(json.dumps(s, indent=2))
EOF
say "done; figures in $out/"
