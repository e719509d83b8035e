//! `dvnav bench`.

use clap::{Args, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;

/// Measure the simulator, the learner and the transport; `--json` prints one object.
#[derive(Args, Debug)]
pub struct BenchArgs {
    #[command(subcommand)]
    what: BenchWhat,
}

#[derive(Subcommand, Debug)]
enum BenchWhat {
    /// Environment steps/s in a room, env0 by default (kinematics, collision check, full scan,
    /// reward): one environment on one thread, and a VecEnv on all threads.
    Env {
        /// Steps timed per measurement.
        #[arg(long, default_value_t = 20_000)]
        steps: usize,
        /// The room: a built-in name, a room file or an occupancy-grid map (the first room of a
        /// file with several), as `dvnav eval --room` takes.
        #[arg(long, default_value = "env0")]
        room: String,
        /// Print one JSON object.
        #[arg(long)]
        json: bool,
    },
    /// Transitions/s from one actor stream into a learner over loopback gRPC (validation and
    /// replay insertion included, no training).
    Transport {
        /// Transitions sent.
        #[arg(long, default_value_t = 50_000)]
        transitions: usize,
        /// Transitions per batch.
        #[arg(long, default_value_t = 128)]
        batch: usize,
        /// Print one JSON object.
        #[arg(long)]
        json: bool,
    },
    /// Replay buffer: memory per transition and observations stored per transition when
    /// filled from real episodes (env0, PID with noise), insertion rate, and sampling time.
    Replay {
        /// Transitions to fill (the paper's buffer: 500,000; its memory: docs/results.md).
        #[arg(long, default_value_t = 500_000)]
        capacity: usize,
        /// Minibatch size sampled.
        #[arg(long, default_value_t = 256)]
        batch: usize,
        /// Print one JSON object.
        #[arg(long)]
        json: bool,
    },
    /// SAC updates/s at a batch size, and policy inference latency at batch 1 and 64.
    Learner {
        /// Config whose network and SAC settings are measured (default: the defaults).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Minibatch size.
        #[arg(long, default_value_t = 256)]
        batch: usize,
        /// Updates timed.
        #[arg(long, default_value_t = 20)]
        updates: usize,
        /// Learner threads, each taking a share of the minibatch (default: the config's
        /// `learner.threads`; 0: one per core). PyTorch with --torch gets the same number.
        #[arg(long)]
        threads: Option<usize>,
        /// `cpu`, or `cuda` / `cuda:N` (a build with `--features cuda`).
        #[arg(long, default_value = "cpu")]
        device: String,
        /// Also time the same update in PyTorch (`scripts/bench_torch.py`, same batch,
        /// threads and device) if Python with torch is found: $DVNAV_TORCH_PYTHON, ./.venv/bin/python3 or
        /// python3; the script: $DVNAV_TORCH_SCRIPT, the checkout this binary was built from,
        /// or ./scripts/. The Rust figure never depends on it.
        #[arg(long)]
        torch: bool,
        /// With --torch: alternate dvnav and PyTorch this many times and report each side's
        /// median, so a load change on a shared machine hits both alike.
        #[arg(long, default_value_t = 3)]
        rounds: usize,
        /// Time the update on the newest checkpoint of this run directory (trained weights
        /// and optimizer moments) instead of fresh networks.
        #[arg(long, value_name = "RUN_DIR")]
        from_checkpoint: Option<PathBuf>,
        /// Keep subnormal floats on the timing thread (the trainer flushes them to zero); to
        /// measure what flushing buys.
        #[arg(long)]
        keep_denormals: bool,
        /// The update's matrix products: `fp32`, `bf16` operands with fp32 sums, or `auto`
        /// (both timed first at this batch and threads, bf16 only if >= 5 % faster; the
        /// JSON's `precision` and `precision_choice` say which ran and why) (default: the
        /// config's `learner.precision`, `auto`). bf16 can be faster only on CPUs with
        /// AVX512-BF16 (`cpu_bf16` in the JSON); elsewhere it computes the same numbers at
        /// fp32 speed.
        /// PyTorch with --torch runs fp32 and bf16 autocast whatever this says.
        #[arg(long)]
        precision: Option<dvnav_config::Precision>,
        /// On a CUDA device, capture the update once as a CUDA graph and replay it instead of
        /// launching its kernels one by one (`learner.cuda_graph`).
        #[arg(long)]
        cuda_graph: bool,
        /// On a CUDA device, also run 8 updates both ways (replayed graphs and op by op) from
        /// the same networks, batches and noise, and report how far apart the two learners end
        /// (`cuda_graph_check` in the JSON).
        #[arg(long)]
        check_cuda_graph: bool,
        /// Print one JSON object.
        #[arg(long)]
        json: bool,
    },
    /// Path planning time (`dvnav_sim::planner`, one thread, on the room's planning raster)
    /// for random starts and goals anywhere in a room that the robot can drive between
    /// (seed 0): p50, p99 and max per plan, and the raster's build time.
    Plan {
        /// The room: a built-in name, a room file or an occupancy-grid map.
        #[arg(long, default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/maps/willow.yaml"))]
        room: String,
        /// The robot's radius (m).
        #[arg(long, default_value_t = 0.2)]
        radius: f64,
        /// Plans timed.
        #[arg(long, default_value_t = 1_000)]
        plans: usize,
        /// Print one JSON object.
        #[arg(long)]
        json: bool,
    },
    /// DVST controller latency at batch 1 (`dvnav serve`): `Act` round trips over loopback
    /// gRPC, and the same commands in-process (checks, DVST and the policy, no network), with
    /// the meta agent's scan layout and with a 1,081-reading LaserScan; then a fleet of robots
    /// on one server (100 at 10 Hz by default).
    Serve {
        /// The meta agent (default: the shipped `models/meta-r0.2`).
        #[arg(long)]
        checkpoint: Option<PathBuf>,
        /// The robot (default: `footprints/paper-medium.toml`, μ = 1.85).
        #[arg(long)]
        footprint: Option<PathBuf>,
        /// Commands timed each way (after 50 warm-up calls).
        #[arg(long, default_value_t = 2_000)]
        calls: usize,
        /// Robots of the fleet driven at once, each on its own connection with its own id.
        #[arg(long, default_value_t = 100)]
        robots: usize,
        /// Each fleet robot's control rate (Hz).
        #[arg(long, default_value_t = 10.0)]
        rate_hz: f64,
        /// How long the fleet drives (s, after 1 s of settling).
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// Then a routed fleet as big, at the same rate, for as long: the server plans each
        /// robot's legs on this map (SetMap, SetGoal) and each Act carries the robot's pose.
        /// '' skips it.
        #[arg(long, default_value = "maps/willow.yaml")]
        route_map: String,
        /// Every this many calls each routed robot reports a pose far from its path (the next
        /// leg's start), so that the server replans inside that Act.
        #[arg(long, default_value_t = 50)]
        stray_every: usize,
        /// Every Act says its scan is this old (s, 0 to 2): the server carries it forward by
        /// the commands it sent that robot (latency compensation) in every part of the bench.
        #[arg(long, default_value_t = 0.0)]
        scan_age_s: f64,
        /// The server runs the collision monitor with this horizon (s; `dvnav serve
        /// --safety-horizon`) in every part of the bench. 0: off.
        #[arg(long, value_name = "S", default_value_t = 0.0)]
        safety_horizon: f64,
        /// Print one JSON object.
        #[arg(long)]
        json: bool,
    },
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// What `scripts/bench_torch.py` prints (one JSON object); typed, so a renamed field fails
/// loudly instead of reading as no figure.
#[derive(Debug, serde::Deserialize)]
struct TorchFigure {
    torch_sac_updates_per_s: f64,
    #[serde(default)]
    torch_gemm_peak_gflops_fp32: Option<f64>,
    #[serde(default)]
    torch_gemm_peak_gflops_bf16: Option<f64>,
}

/// Where `scripts/bench_torch.py` is: $DVNAV_TORCH_SCRIPT, else the checkout this binary was
/// built from, else the current directory's `scripts/` (a binary carried to another machine,
/// such as `make gpu-bin`'s, run from a checkout there).
fn torch_script() -> std::path::PathBuf {
    if let Some(p) = std::env::var_os("DVNAV_TORCH_SCRIPT") {
        return p.into();
    }
    let built = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/bench_torch.py");
    if built.exists() { built } else { std::path::PathBuf::from("scripts/bench_torch.py") }
}

/// Runs `scripts/bench_torch.py` at `precision` (`fp32`, or `bf16` under autocast), with its
/// matrix-product peaks when `peak`, on the GPU when `cuda`; `Err` says why there is no
/// PyTorch figure.
fn torch_figure(
    batch: usize,
    threads: usize,
    updates: usize,
    precision: &str,
    peak: bool,
    cuda: bool,
) -> Result<TorchFigure, String> {
    let script = torch_script();
    let python = std::env::var("DVNAV_TORCH_PYTHON").ok().unwrap_or_else(|| {
        let venv = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv/bin/python3");
        if venv.exists() { venv.display().to_string() } else { "python3".into() }
    });
    let mut cmd = std::process::Command::new(&python);
    cmd.arg(&script)
        .args(["--batch", &batch.to_string(), "--threads", &threads.to_string()])
        .args(["--updates", &updates.to_string(), "--precision", precision]);
    if peak {
        cmd.arg("--peak");
    }
    if cuda {
        // The peer on the same device: PyTorch on its first GPU.
        cmd.args(["--device", "cuda"]);
    }
    let out = cmd.output().map_err(|e| format!("cannot run {python}: {e}"))?;
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        let last = err.lines().last().unwrap_or("").to_string();
        return Err(format!("{python} {}: {last}", script.display()));
    }
    serde_json::from_slice(&out.stdout).map_err(|e| format!("unreadable output: {e}"))
}

/// PyTorch's side of `dvnav bench learner --torch`: medians over the alternated rounds.
#[derive(Debug, Default, serde::Serialize)]
struct TorchSide {
    torch_sac_updates_per_s: Option<f64>,
    torch_bf16_sac_updates_per_s: Option<f64>,
    torch_gemm_peak_gflops_fp32: Option<f64>,
    torch_gemm_peak_gflops_bf16: Option<f64>,
}

/// Times dvnav, PyTorch fp32 and PyTorch bf16 autocast in turn, `rounds` times, so that a load
/// change on a shared machine hits all alike; sets `r` to dvnav's median.
fn alternate_with_torch(
    cfg: &dvnav_config::Config,
    r: &mut dvnav_learner::bench::LearnerBench,
    run: &dvnav_learner::bench::UpdateBench,
    rounds: usize,
    dev: &dvnav_learner::device::Device,
) -> anyhow::Result<TorchSide> {
    let (batch, threads, updates) = (r.batch, r.threads, r.updates);
    let cuda = !dev.is_cpu();
    // The later rounds time the update alone: the peak is the first round's.
    let run = dvnav_learner::bench::UpdateBench { warmup: 1, measure_peak: false, ..run.clone() };
    let (mut ours, mut fp32, mut bf16) = (vec![r.sac_updates_per_s], Vec::new(), Vec::new());
    let mut side = TorchSide::default();
    for round in 0..rounds.max(1) {
        if round > 0 {
            let again = dvnav_learner::bench::sac_updates(cfg, &run, dev)?;
            ours.push(again.sac_updates_per_s);
        }
        match torch_figure(batch, threads, updates, "fp32", round == 0, cuda) {
            Ok(v) => {
                fp32.push(v.torch_sac_updates_per_s);
                if round == 0 {
                    side.torch_gemm_peak_gflops_fp32 = v.torch_gemm_peak_gflops_fp32;
                    side.torch_gemm_peak_gflops_bf16 = v.torch_gemm_peak_gflops_bf16;
                }
            }
            Err(why) => {
                eprintln!("PyTorch comparison skipped: {why}");
                break;
            }
        }
        match torch_figure(batch, threads, updates, "bf16", false, cuda) {
            Ok(v) => bf16.push(v.torch_sac_updates_per_s),
            Err(why) => eprintln!("PyTorch bf16 autocast skipped: {why}"),
        }
    }
    r.set_rate(median(&mut ours));
    side.torch_sac_updates_per_s = (!fp32.is_empty()).then(|| median(&mut fp32));
    side.torch_bf16_sac_updates_per_s = (!bf16.is_empty()).then(|| median(&mut bf16));
    Ok(side)
}

pub fn run(args: BenchArgs) -> anyhow::Result<ExitCode> {
    match args.what {
        BenchWhat::Env { steps, room, json } => {
            let r = bench_env(steps, &room)?;
            if json {
                println!("{r}");
            } else {
                println!(
                    "env steps/s in {}: {:.0} on 1 thread, {:.0} on {} threads ({} envs)",
                    r["room"].as_str().unwrap_or("?"),
                    r["env_steps_per_s_1thread"].as_f64().unwrap_or(0.0),
                    r["env_steps_per_s_all_threads"].as_f64().unwrap_or(0.0),
                    r["threads"],
                    r["envs"]
                );
            }
        }
        BenchWhat::Transport { transitions, batch, json } => {
            let r = super::runtime()?.block_on(bench_transport(transitions, batch))?;
            if json {
                println!("{r}");
            } else {
                println!(
                    "transport: {:.0} transitions/s ({:.1} MB/s of encoded batches) over loopback gRPC, batch {}",
                    r["transitions_per_s"].as_f64().unwrap_or(0.0),
                    r["mb_per_s"].as_f64().unwrap_or(0.0),
                    batch
                );
            }
        }
        BenchWhat::Replay { capacity, batch, json } => {
            let cfg = dvnav_config::Config::default();
            let r = dvnav_learner::bench::replay(&cfg, capacity, batch)?;
            if json {
                println!("{}", serde_json::to_string(&r)?);
            } else {
                println!(
                    "replay: {} transitions in {:.0} MiB ({:.0} B each; two f32 copies: {:.0} MiB), {:.3} observations per transition, {:.0} inserts/s, {:.0} µs per batch of {}",
                    r.transitions,
                    r.memory_mib,
                    r.bytes_per_transition,
                    r.naive_memory_mib,
                    r.observations_per_transition,
                    r.insert_per_s,
                    r.sample_us,
                    r.batch
                );
            }
        }
        BenchWhat::Learner {
            config,
            batch,
            updates,
            threads,
            device,
            torch,
            rounds,
            from_checkpoint,
            keep_denormals,
            precision,
            cuda_graph,
            check_cuda_graph,
            json,
        } => {
            let mut cfg = super::load_config(config.as_ref())?;
            if let Some(p) = precision {
                cfg.learner.precision = p;
            }
            cfg.learner.cuda_graph |= cuda_graph;
            let threads = match threads.unwrap_or(cfg.learner.threads) {
                0 => std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1),
                n => n,
            };
            super::candle_single_threaded();
            let dev = dvnav_learner::device::parse(&device)?;
            let run = dvnav_learner::bench::UpdateBench {
                batch,
                threads,
                warmup: 3,
                updates,
                checkpoint: from_checkpoint,
                flush_denormals: !keep_denormals,
                measure_peak: true,
            };
            let graph_check = if check_cuda_graph {
                let c = dvnav_learner::bench::cuda_graph_check(&cfg, batch, 8, &dev)?;
                if !json {
                    println!(
                        "CUDA graph against op by op after {} updates: largest difference {:.3e} (largest value {:.3e}){}",
                        c.updates,
                        c.max_abs_diff,
                        c.max_abs_value,
                        if c.replayed { "" } else { "; no graph was replayed" }
                    );
                }
                Some(c)
            } else {
                None
            };
            // `auto` is timed at the bench's own batch and threads.
            let (chosen, choice) = {
                let mut at = cfg.clone();
                (at.sac.batch_size, at.learner.threads) = (batch, threads);
                dvnav_learner::bench::precision::resolve(&at, &dev)?
            };
            cfg.learner.precision = chosen;
            if let (Some(c), false) = (&choice, json) {
                println!("precision auto: {c}");
            }
            let mut r = dvnav_learner::bench::sac_updates(&cfg, &run, &dev)?;
            r.precision_choice = choice;
            let side = if torch {
                alternate_with_torch(&cfg, &mut r, &run, rounds, &dev)?
            } else {
                TorchSide::default()
            };
            let ratio = |t: Option<f64>| t.map(|t| r.sac_updates_per_s / t);
            if json {
                let mut v = serde_json::to_value(&r)?;
                let extra = serde_json::to_value(&side)?;
                for (k, x) in extra.as_object().into_iter().flatten() {
                    v[k] = x.clone();
                }
                v["speed_ratio_vs_torch"] = serde_json::json!(ratio(side.torch_sac_updates_per_s));
                v["speed_ratio_vs_torch_bf16"] =
                    serde_json::json!(ratio(side.torch_bf16_sac_updates_per_s));
                if let Some(c) = graph_check {
                    v["cuda_graph_check"] = serde_json::to_value(c)?;
                }
                println!("{v}");
            } else {
                if let Some(t) = side.torch_sac_updates_per_s {
                    println!(
                        "PyTorch, same network, batch and threads: {t:.2} updates/s; dvnav/PyTorch = {:.2}",
                        r.sac_updates_per_s / t
                    );
                }
                if let Some(t) = side.torch_bf16_sac_updates_per_s {
                    println!(
                        "PyTorch bf16 autocast: {t:.2} updates/s; dvnav/PyTorch bf16 = {:.2}",
                        r.sac_updates_per_s / t
                    );
                }
                if let (Some(p), Some(f)) = (r.gemm_peak_gflops_fp32, r.fraction_of_peak_fp32) {
                    println!(
                        "{:.2} GFLOP per update, {:.1} GFLOP/s = {:.0} % of the measured fp32 matrix-product peak ({p:.1} GFLOP/s at {} threads)",
                        r.update_gflop,
                        r.gflops,
                        100.0 * f,
                        r.threads
                    );
                }
                match r.gemm_peak_gflops_bf16 {
                    Some(p) => println!("bf16 matrix-product peak (AVX512-BF16): {p:.1} GFLOP/s"),
                    None => println!("no AVX512-BF16 on this CPU: bf16 runs at fp32 speed"),
                }
                println!(
                    "SAC updates/s at batch {} in {}: {:.2} ({:.1} ms/update), {} threads, {}; inference {:.2} ms (batch 1), {:.2} ms (batch 64)",
                    r.batch,
                    r.precision,
                    r.sac_updates_per_s,
                    r.ms_per_update,
                    r.threads,
                    r.network,
                    r.inference_ms_batch1,
                    r.inference_ms_batch64
                );
            }
        }
        BenchWhat::Plan { room, radius, plans, json } => {
            let r = bench_plan(&room, radius, plans)?;
            if json {
                println!("{r}");
            } else {
                println!(
                    "planning in {} ({}² cells of {:.4} m, built in {:.0} ms, {:.0} m² reachable), radius {radius} m: p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms over {plans} plans (mean path {:.1} m, {} failed)",
                    r["room"].as_str().unwrap_or("?"),
                    r["cells_per_side"],
                    r["cell_m"].as_f64().unwrap_or(0.0),
                    r["map_build_ms"].as_f64().unwrap_or(0.0),
                    r["reachable_m2"].as_f64().unwrap_or(0.0),
                    r["p50_ms"].as_f64().unwrap_or(0.0),
                    r["p99_ms"].as_f64().unwrap_or(0.0),
                    r["max_ms"].as_f64().unwrap_or(0.0),
                    r["mean_path_m"].as_f64().unwrap_or(0.0),
                    r["failed"],
                );
            }
        }
        BenchWhat::Serve {
            checkpoint,
            footprint,
            calls,
            robots,
            rate_hz,
            seconds,
            route_map,
            stray_every,
            scan_age_s,
            safety_horizon,
            json,
        } => {
            let repo = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
            let checkpoint = checkpoint.unwrap_or_else(|| repo.join("models/meta-r0.2"));
            let footprint = footprint.unwrap_or_else(|| repo.join("footprints/paper-medium.toml"));
            let fleet = super::serve::FleetLoad {
                robots,
                rate_hz,
                seconds,
                scan_age_s,
                safety_horizon_s: safety_horizon,
            };
            // A relative map path names a file of the repository, as the defaults above do.
            let route = (!route_map.is_empty()).then(|| super::serve::RouteLoad {
                map: match std::path::Path::new(&route_map) {
                    p if p.is_absolute() || p.exists() => p.to_path_buf(),
                    p => repo.join(p),
                },
                robots,
                rate_hz,
                seconds,
                stray_every,
            });
            let r = super::serve::bench(&checkpoint, &footprint, calls, fleet, route)?;
            if json {
                println!("{}", serde_json::to_string(&r)?);
            } else {
                println!("{}", r.summary());
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn bench_env(steps: usize, room: &str) -> anyhow::Result<serde_json::Value> {
    use dvnav_config::Config;
    use dvnav_sim::{NavEnv, Room};
    use rayon::prelude::*;
    use std::time::Instant;
    let cfg = Config::default();
    let room =
        Room::load(room)?.into_iter().next().ok_or_else(|| anyhow::anyhow!("no room to step"))?;
    // A gently turning drive: long enough episodes, some collisions, like an early policy.
    let command = |k: usize| (0.4, if (k / 20).is_multiple_of(2) { 0.6 } else { -0.6 });

    // The same 64 environments (32 per thread on 2 cores: a round outweighs rayon's fork-join
    // cost) stepped, and reset when done, on a 1-thread pool and then on all threads.
    let threads = rayon::current_num_threads();
    let n = 32 * threads.max(2);
    let rounds = (steps / n).max(1);
    let measure = |pool: &rayon::ThreadPool| -> f64 {
        let mut envs: Vec<NavEnv> =
            (0..n as u64).map(|seed| NavEnv::new(room.clone(), &cfg.env, seed)).collect();
        pool.install(|| {
            let t = Instant::now();
            for k in 0..rounds {
                let (v, w) = command(k);
                envs.par_iter_mut().for_each(|env| {
                    if env.step(v, w).done.is_some() {
                        env.reset();
                    }
                });
            }
            (rounds * n) as f64 / t.elapsed().as_secs_f64()
        })
    };
    let one = measure(&rayon::ThreadPoolBuilder::new().num_threads(1).build()?);
    let all = measure(&rayon::ThreadPoolBuilder::new().num_threads(threads).build()?);

    // One environment on its own (cache-hot), as a lower bound on a step's cost.
    let mut env = NavEnv::new(room.clone(), &cfg.env, 1);
    let t = Instant::now();
    for k in 0..steps {
        let (v, w) = command(k);
        if env.step(v, w).done.is_some() {
            env.reset();
        }
    }
    let single = steps as f64 / t.elapsed().as_secs_f64();
    Ok(serde_json::json!({
        "env_steps_per_s_1thread": one,
        "env_steps_per_s_all_threads": all,
        "scaling": all / one,
        "single_env_steps_per_s": single,
        "threads": threads,
        "envs": n,
        "room": room.name(),
        "beams": cfg.env.lidar.beams,
    }))
}

/// Times [`dvnav_sim::planner::plan`] between random starts and goals anywhere in the room
/// that the robot can drive between (two passable cells of one component of the planner's own
/// raster, at least 1 m apart, drawn uniformly over the passable cells, seed 0).
fn bench_plan(room: &str, radius: f64, plans: usize) -> anyhow::Result<serde_json::Value> {
    use dvnav_sim::Room;
    use dvnav_sim::planner::{PlannerConfig, plan};
    use rand::SeedableRng;
    use std::time::Instant;
    anyhow::ensure!(plans > 0, "--plans must be at least 1");
    anyhow::ensure!(radius > 0.0 && radius.is_finite(), "--radius must be above 0 m");
    let room: std::sync::Arc<Room> = Room::load(room)?
        .into_iter()
        .next()
        .ok_or_else(|| anyhow::anyhow!("no room to plan in"))?;
    let t = Instant::now();
    let map = room.planning_map();
    let build_ms = t.elapsed().as_secs_f64() * 1e3;
    let reach = map.reach(radius);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0);
    let cfg = PlannerConfig::default();
    let pairs = reach.random_connected_pairs(&mut rng, plans, 1.0).ok_or_else(|| {
        anyhow::anyhow!(
            "no two points 1 m apart that a robot of radius {radius} m can drive between in {}",
            room.name()
        )
    })?;
    let (mut times, mut lengths, mut failed) = (Vec::with_capacity(plans), Vec::new(), 0usize);
    for (a, b) in pairs {
        let t = Instant::now();
        let out = plan(map, radius, a, b, &cfg);
        times.push(t.elapsed().as_secs_f64() * 1e3);
        match out {
            Ok(p) => lengths.push(p.length_m),
            Err(_) => failed += 1,
        }
    }
    times.sort_by(f64::total_cmp);
    let pct = |q: f64| times[((times.len() - 1) as f64 * q).round() as usize];
    Ok(serde_json::json!({
        "room": room.name(),
        "radius_m": radius,
        "cells_per_side": map.raster().n,
        "cell_m": map.raster().res,
        "map_build_ms": build_ms,
        // Where the robot can go from the largest component's cells, on this raster and on
        // the coarser one that tasks are drawn on (conservative cells narrow every door).
        "reachable_m2": reach.largest_area_m2(),
        "sampling_cell_m": room.clearance_map().raster().res,
        "sampling_reachable_m2": room.reach(radius).largest_area_m2(),
        "plans": plans,
        "p50_ms": pct(0.5),
        "p99_ms": pct(0.99),
        "max_ms": times[times.len() - 1],
        "mean_ms": times.iter().sum::<f64>() / times.len() as f64,
        "mean_path_m": lengths.iter().sum::<f64>() / lengths.len().max(1) as f64,
        "failed": failed,
        "threads": 1,
    }))
}

async fn bench_transport(transitions: usize, batch: usize) -> anyhow::Result<serde_json::Value> {
    use dvnav_config::Config;
    use dvnav_learner::service::LearnerService;
    use dvnav_learner::state::LearnerState;
    use dvnav_link::core::TransitionBatch;
    use std::sync::Arc;
    use std::time::{Duration, Instant};

    let mut cfg = Config::default();
    // No training and no throttling: only the wire, validation and replay insertion are timed.
    cfg.sac.learning_starts = u64::MAX / 2;
    cfg.run.steps = u64::MAX / 2;
    cfg.replay.capacity = transitions.max(batch);
    let state = Arc::new(LearnerState::new(cfg.clone(), "bench".into(), None, vec![]));
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let addr = listener.local_addr()?;
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let server = tokio::spawn(
        dvnav_learner::service::transport_server(None)?
            .add_service(LearnerService::server(state.clone()))
            .serve_with_incoming_shutdown(
                tokio_stream::wrappers::TcpListenerStream::new(listener),
                async {
                    let _ = stop_rx.await;
                },
            ),
    );
    let mut client =
        dvnav_actor::run::connect(&format!("http://{addr}"), None, None, Duration::from_secs(10))
            .await?;
    let reg = client
        .register(dvnav_proto::RegisterRequest {
            actor_name: "bench".into(),
            protocol_version: dvnav_proto::PROTOCOL_VERSION,
            num_envs: 1,
        })
        .await?
        .into_inner();
    let id = reg.actor_id;
    let d = cfg.obs_dim();
    let mut b = TransitionBatch::with_capacity(d, batch);
    let obs: Vec<f32> = (0..d).map(|i| 0.5 + (i % 50) as f32 * 0.1).collect();
    for _ in 0..batch {
        b.push(&obs, [0.1, -0.2], 0.01, &obs, false, false, 1);
    }
    let n_batches = transitions.div_ceil(batch);
    // Bytes on the wire per batch: the encoded body (the two header fields add a few more).
    let batch_bytes = dvnav_link::wire::EncodedBatch::new(&b).body_len();
    let t = Instant::now();
    // As an actor sends: each batch encoded once (timed, as the encoding always was), its bytes
    // written as they are.
    let msgs = (0..n_batches).map(move |s| dvnav_actor::learner_link::Outgoing {
        actor_id: id,
        sequence: s as u64,
        batch: dvnav_link::wire::EncodedBatch::new(&b),
    });
    let mut acks =
        client.transitions_encoded(&reg.session, tokio_stream::iter(msgs)).await?.into_inner();
    let mut accepted = 0u64;
    while let Some(a) = acks.message().await? {
        accepted += a.accepted as u64;
    }
    let secs = t.elapsed().as_secs_f64();
    let _ = stop_tx.send(());
    state.begin_shutdown();
    server.await??;
    anyhow::ensure!(
        accepted == (n_batches * batch) as u64,
        "only {accepted} transitions acknowledged"
    );
    let bytes = (n_batches * batch_bytes) as f64;
    Ok(serde_json::json!({
        "transitions_per_s": accepted as f64 / secs,
        "mb_per_s": bytes / secs / 1e6,
        "transitions": accepted,
        "batch": batch,
        "obs_dim": d,
    }))
}
