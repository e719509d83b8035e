#!/usr/bin/env python3
"""dvnav side by side with Stable-Baselines3 on this machine (`make bench-peers`).

1. Environment steps/s through Python: one `dvnav/Nav-v0` stepped from Python (gymnasium.make,
   its checker wrappers included), and the vector environment (`gymnasium.make_vec`) at several
   sizes, resets included (episodes end and restart inside the timed loop).
2. Time to skill, alternated seed by seed on the same cores: `dvnav train --actors 2
   --stop-when-skilled` (the default config: curriculum Env_0..Env_3, a stage passes at >= 90 %
   success over its last 50 training episodes) against SB3's SAC on `dvnav/Nav-v0` with the
   same curriculum and rule, the same network (dvnav's 1D-CNN scan encoder as SB3's features
   extractor, then 256-256), and dvnav's SAC settings (batch 128, learning rate 3e-4, gamma
   0.99, tau 0.005, 2,000 transitions before learning, 0.25 updates per environment step,
   8 environments). SB3 has no PID warm-up; it starts from random actions, as SB3 does. A run
   that is not skilled within --sb3-budget-s stops there and is reported as such.

Prints one JSON object per measurement and writes them all to OUT/peers.json.
Usage: bench_peers.py DVNAV_BIN [--seeds 3] [--seed 1] [--sb3-budget-s 900] [--out DIR]
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import gymnasium
import numpy as np

import dvnav

ROOT = Path(__file__).resolve().parent.parent
CURRICULUM = ["env0", "env1", "env2", "env3"]
WINDOW, THRESHOLD = 50, 0.9


def emit(out: list, row: dict) -> None:
    out.append(row)
    print(json.dumps(row), flush=True)


def env_steps_per_s(out: list) -> None:
    env = gymnasium.make("dvnav/Nav-v0", room="env3", seed=0)
    env.reset()
    action = np.array([0.2, 0.3], np.float32)
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < 5.0:
        for _ in range(1000):
            _, _, te, tr, _ = env.step(action)
            if te or tr:
                env.reset()
        n += 1000
    emit(out, {"bench": "python_env", "num_envs": 1, "steps_per_s": n / (time.perf_counter() - t0)})
    for num_envs in (16, 64, 256):
        envs = gymnasium.make_vec("dvnav/Nav-v0", num_envs=num_envs, room="env3", seed=0)
        envs.reset()
        actions = np.tile(action, (num_envs, 1))
        steps, resets, t0 = 0, 0, time.perf_counter()
        while time.perf_counter() - t0 < 5.0:
            for _ in range(100):
                _, _, te, tr, _ = envs.step(actions)
                resets += int((te | tr).sum())
            steps += 100 * num_envs
        dt = time.perf_counter() - t0
        emit(out, {"bench": "python_vector_env", "num_envs": num_envs,
                   "steps_per_s": steps / dt, "episodes_ended": resets})


def dvnav_time_to_skill(out: list, bin_: str, seed: int, run_dir: Path) -> None:
    run = run_dir / f"dvnav-seed-{seed}"
    t0 = time.perf_counter()
    subprocess.run([bin_, "train", "--actors", "2", "--seed", str(seed), "--stop-when-skilled",
                    "--steps", "200000", "--out", str(run), "--progress-every-s", "60"],
                   check=True, cwd=ROOT, stdout=sys.stderr)
    wall = time.perf_counter() - t0
    summary = json.loads((run / "run_summary.json").read_text())
    skilled = summary.get("skilled")
    emit(out, {"bench": "time_to_skill", "tool": "dvnav", "seed": seed,
               "skilled": skilled is not None,
               "time_to_skill_s": summary["wall_time_s"] if skilled else None,
               "env_steps": skilled["env_steps"] if skilled else None,
               "updates": skilled["updates"] if skilled else None,
               "wall_s": wall, "stage": summary.get("stage")})


def sb3_time_to_skill(out: list, seed: int, budget_s: float, threads: int) -> None:
    import torch
    import torch.nn as nn
    import torch.nn.functional as F
    from stable_baselines3 import SAC
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

    torch.set_num_threads(threads)

    class ScanEncoder(BaseFeaturesExtractor):
        """dvnav's scan encoder (design §3): 1/(d + a) -> Conv1d(1->32, k20, s5) -> LeakyReLU ->
        Conv1d(32->32, k10, s3) -> LeakyReLU -> Linear(->128) -> LeakyReLU, with the goal and
        velocity appended: 132 features."""

        def __init__(self, space, beams: int = 540):
            super().__init__(space, features_dim=128 + space.shape[0] - beams)
            self.beams = beams
            self.offset = nn.Parameter(torch.zeros(1))
            self.conv1 = nn.Conv1d(1, 32, 20, stride=5)
            self.conv2 = nn.Conv1d(32, 32, 10, stride=3)
            self.fc = nn.Linear(32 * 32, 128)

        def forward(self, obs):
            x = 1.0 / (obs[:, : self.beams] + self.offset).clamp(min=1e-2)
            x = F.leaky_relu(self.conv1(x.unsqueeze(1)), 0.01)
            x = F.leaky_relu(self.conv2(x), 0.01)
            x = F.leaky_relu(self.fc(x.flatten(1)), 0.01)
            return torch.cat([x, obs[:, self.beams :]], 1)

    class Curriculum(BaseCallback):
        """dvnav's curriculum rule on SB3's training episodes; stops when skilled or out of time."""

        def __init__(self):
            super().__init__()
            self.stage, self.window = 0, collections.deque(maxlen=WINDOW)
            self.t0 = time.perf_counter()
            self.skilled_at = None
            self.changes = []

        def _on_step(self) -> bool:
            for done, info in zip(self.locals["dones"], self.locals["infos"]):
                if not done:
                    continue
                self.window.append(bool(info.get("is_success", False)))
                if len(self.window) == WINDOW and sum(self.window) / WINDOW >= THRESHOLD:
                    elapsed = time.perf_counter() - self.t0
                    self.changes.append({"stage": self.stage, "env_steps": self.num_timesteps,
                                         "s": elapsed})
                    if self.stage == len(CURRICULUM) - 1:
                        self.skilled_at = (elapsed, self.num_timesteps)
                        return False
                    self.stage += 1
                    self.window.clear()
                    self.training_env.env_method("set_room", CURRICULUM[self.stage])
            return time.perf_counter() - self.t0 < budget_s

    t0 = time.perf_counter()
    envs = make_vec_env("dvnav/Nav-v0", n_envs=8, seed=seed, env_kwargs={"room": CURRICULUM[0]})
    model = SAC(
        "MlpPolicy", envs, seed=seed, batch_size=128, learning_rate=3e-4, gamma=0.99, tau=0.005,
        learning_starts=2000, buffer_size=500_000, train_freq=1, gradient_steps=2,
        policy_kwargs={"features_extractor_class": ScanEncoder, "net_arch": [256, 256]},
    )
    cb = Curriculum()
    cb.t0 = t0
    model.learn(total_timesteps=10_000_000, callback=cb)
    wall = time.perf_counter() - t0
    emit(out, {"bench": "time_to_skill", "tool": "sb3", "seed": seed,
               "skilled": cb.skilled_at is not None,
               "time_to_skill_s": cb.skilled_at[0] if cb.skilled_at else None,
               "env_steps": cb.skilled_at[1] if cb.skilled_at else model.num_timesteps,
               "updates": model._n_updates, "wall_s": wall, "stage": cb.stage,
               "stage_changes": cb.changes, "budget_s": budget_s,
               "updates_per_s": model._n_updates / wall})


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("dvnav_bin")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--sb3-budget-s", type=float, default=900.0,
                   help="seconds an SB3 run may take to become skilled (default 900)")
    p.add_argument("--threads", type=int, default=2, help="torch threads for SB3 (the machine's 2 cores)")
    p.add_argument("--only", choices=["env", "skill"], help="one part only")
    p.add_argument("--out", type=Path, default=ROOT / "runs" / "peers")
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    out: list = []
    emit(out, {"bench": "machine", "cpus": os.cpu_count(), "dvnav": dvnav.__version__,
               "gymnasium": gymnasium.__version__})
    if args.only in (None, "env"):
        env_steps_per_s(out)
    if args.only in (None, "skill"):
        # Alternated: dvnav seed s, then SB3 seed s, so both see the same machine state.
        for seed in range(args.seed, args.seed + args.seeds):
            dvnav_time_to_skill(out, args.dvnav_bin, seed, args.out)
            sb3_time_to_skill(out, seed, args.sb3_budget_s, args.threads)
        by = collections.defaultdict(list)
        for r in out:
            if r["bench"] == "time_to_skill" and r["skilled"]:
                by[r["tool"]].append(r["time_to_skill_s"])
        row = {"bench": "time_to_skill_ratio", "dvnav_skilled": len(by["dvnav"]),
               "sb3_skilled": len(by["sb3"]), "seeds": args.seeds}
        if by["dvnav"]:
            dv = float(np.median(by["dvnav"]))
            row["dvnav_median_s"] = dv
            if len(by["sb3"]) == args.seeds:
                row["sb3_over_dvnav"] = float(np.median(by["sb3"])) / dv
            else:
                # Unskilled SB3 runs count as at least their budget: a lower bound on the ratio.
                times = by["sb3"] + [args.sb3_budget_s] * (args.seeds - len(by["sb3"]))
                row["sb3_over_dvnav_at_least"] = float(np.median(times)) / dv
        emit(out, row)
    (args.out / "peers.json").write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
