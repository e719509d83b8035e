#!/usr/bin/env python3
"""PyTorch reference for `dvnav bench learner`: the same SAC update on the same network.

Network (dvnav's default, design §3): scan -> 1/(d + a) with a learned scalar a -> Conv1d(1->32,
k20, s5) -> LeakyReLU -> Conv1d(32->32, k10, s3) -> LeakyReLU -> flatten -> Linear(->128) ->
LeakyReLU -> concat [goal distance, goal angle, v, omega] (+ action for a critic) ->
Linear(->256) -> ReLU -> Linear(256->256) -> ReLU -> head. Policy: tanh-squashed Gaussian.
Two critics with target copies.

One update, as dvnav's `SacLearner::update`: soft Bellman target with the twin-Q minimum, both
critics' MSE, Adam; every 2nd update the policy loss (alpha log pi - min Q + L2 of the policy
weights) and the temperature loss; Polyak averaging of both targets every update.

With --precision bf16 the update runs under torch.autocast("cpu", torch.bfloat16) (bf16
matmuls and convolutions, fp32 weights and optimizer), PyTorch's own mixed precision. With
--peak it also times single 512x512 matrix products at the same threads, fp32 and bf16: the
CPU's peak as PyTorch reaches it.

With --device cuda the same update runs on an NVIDIA GPU (autocast("cuda") for bf16), the
clock read after a synchronize: the peer of `dvnav bench learner --device cuda`
(scripts/gpu_check.sh).

Prints one JSON object. Usage: bench_torch.py [--batch 256] [--threads 1] [--updates 20]
[--precision fp32|bf16] [--device cpu|cuda] [--peak]
Install: python3 -m venv .venv && .venv/bin/pip install torch numpy
"""
import argparse
import json
import math
import time

import torch
import torch.nn as nn
import torch.nn.functional as F

BEAMS, EXTRA, ACT = 540, 4, 2


class Encoder(nn.Module):
    def __init__(self):
        super().__init__()
        self.offset = nn.Parameter(torch.zeros(1))
        self.conv1 = nn.Conv1d(1, 32, 20, stride=5)
        self.conv2 = nn.Conv1d(32, 32, 10, stride=3)
        self.fc = nn.Linear(32 * 32, 128)

    def forward(self, scan):
        x = 1.0 / (scan + self.offset).clamp(min=1e-2)
        x = F.leaky_relu(self.conv1(x.unsqueeze(1)), 0.01)
        x = F.leaky_relu(self.conv2(x), 0.01)
        return F.leaky_relu(self.fc(x.flatten(1)), 0.01)


class Actor(nn.Module):
    def __init__(self):
        super().__init__()
        self.enc = Encoder()
        self.fc1 = nn.Linear(128 + EXTRA, 256)
        self.fc2 = nn.Linear(256, 256)
        self.mean = nn.Linear(256, ACT)
        self.log_std = nn.Linear(256, ACT)

    def forward(self, obs):
        h = torch.cat([self.enc(obs[:, :BEAMS]), obs[:, BEAMS:]], 1)
        h = F.relu(self.fc2(F.relu(self.fc1(h))))
        log_std = -5.0 + 0.5 * 7.0 * (torch.tanh(self.log_std(h)) + 1.0)
        return self.mean(h), log_std

    def sample(self, obs):
        mean, log_std = self(obs)
        eps = torch.randn_like(mean)
        u = mean + log_std.exp() * eps
        a = torch.tanh(u)
        logp = (-0.5 * eps.pow(2) - log_std - 0.5 * math.log(2 * math.pi)).sum(1)
        logp = logp - (2.0 * (math.log(2.0) - u - F.softplus(-2.0 * u))).sum(1)
        return a, logp


class Critic(nn.Module):
    def __init__(self):
        super().__init__()
        self.enc = Encoder()
        self.fc1 = nn.Linear(128 + EXTRA + ACT, 256)
        self.fc2 = nn.Linear(256, 256)
        self.q = nn.Linear(256, 1)

    def forward(self, obs, act):
        h = torch.cat([self.enc(obs[:, :BEAMS]), obs[:, BEAMS:], act], 1)
        return self.q(F.relu(self.fc2(F.relu(self.fc1(h))))).squeeze(1)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--batch", type=int, default=256)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--updates", type=int, default=20)
    p.add_argument("--warmup", type=int, default=3)
    p.add_argument("--precision", choices=["fp32", "bf16"], default="fp32")
    p.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    p.add_argument("--peak", action="store_true")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    dev = torch.device(args.device)
    if dev.type == "cuda" and not torch.cuda.is_available():
        p.error("--device cuda: this PyTorch sees no CUDA GPU")
    # Timing reads the clock only once the GPU's queued work is done.
    sync = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)
    torch.set_default_device(dev)

    actor, q1, q2 = Actor(), Critic(), Critic()
    t1, t2 = Critic(), Critic()
    t1.load_state_dict(q1.state_dict())
    t2.load_state_dict(q2.state_dict())
    log_alpha = torch.zeros(1, requires_grad=True, device=dev)
    q_opt = torch.optim.Adam(list(q1.parameters()) + list(q2.parameters()), lr=3e-4)
    pi_opt = torch.optim.Adam(actor.parameters(), lr=3e-4)
    a_opt = torch.optim.Adam([log_alpha], lr=3e-4)
    weights = [w for n, w in actor.named_parameters() if n.endswith("weight")]
    gamma, tau, l2, target_entropy = 0.99, 0.005, 1e-3, -2.0

    b = args.batch
    n = 4 * b
    obs_all = torch.rand(n, BEAMS + EXTRA) * 9.9 + 0.1
    next_all = torch.rand(n, BEAMS + EXTRA) * 9.9 + 0.1
    act_all = torch.rand(n, ACT) * 2 - 1
    rew_all = torch.rand(n) * 2 - 1
    done_all = (torch.rand(n) < 0.05).float()

    def update(step):
        idx = torch.randint(0, n, (b,))
        obs, nxt, act, rew, done = obs_all[idx], next_all[idx], act_all[idx], rew_all[idx], done_all[idx]
        alpha = log_alpha.exp().item()
        with torch.no_grad():
            na, nlogp = actor.sample(nxt)
            target = rew + gamma * (1 - done) * (torch.min(t1(nxt, na), t2(nxt, na)) - alpha * nlogp)
        q_loss = F.mse_loss(q1(obs, act), target) + F.mse_loss(q2(obs, act), target)
        q_opt.zero_grad()
        q_loss.backward()
        q_opt.step()
        if step % 2 == 0:
            a, logp = actor.sample(obs)
            pi_loss = (alpha * logp - torch.min(q1(obs, a), q2(obs, a))).mean()
            pi_loss = pi_loss + l2 * sum(w.pow(2).sum() for w in weights)
            pi_opt.zero_grad()
            pi_loss.backward()
            pi_opt.step()
            alpha_loss = (-log_alpha.exp() * (logp.detach() + target_entropy)).mean()
            a_opt.zero_grad()
            alpha_loss.backward()
            a_opt.step()
        with torch.no_grad():
            for t, q in ((t1, q1), (t2, q2)):
                for tp, qp in zip(t.parameters(), q.parameters()):
                    tp.mul_(1 - tau).add_(tau * qp)

    amp = torch.autocast(dev.type, dtype=torch.bfloat16, enabled=args.precision == "bf16")
    with amp:
        for i in range(args.warmup):
            update(i)
        sync()
        start = time.perf_counter()
        for i in range(args.updates):
            update(i)
        sync()
        secs = time.perf_counter() - start
    out = {
        "torch_sac_updates_per_s": args.updates / secs,
        "precision": args.precision,
        "ms_per_update": 1e3 * secs / args.updates,
        "batch": b,
        "threads": args.threads,
        "device": args.device,
        "torch_version": torch.__version__,
    }
    if dev.type == "cuda":
        out["gpu"] = torch.cuda.get_device_name(dev)
    if args.peak:
        out["torch_gemm_peak_gflops_fp32"] = gemm_gflops(torch.float32, sync)
        out["torch_gemm_peak_gflops_bf16"] = gemm_gflops(torch.bfloat16, sync)
    print(json.dumps(out))


def gemm_gflops(dtype, sync, side=512, seconds=0.5):
    """GFLOP/s of repeated side^3 products in `dtype` at the threads set (on the default
    device; `sync` waits for it)."""
    a = torch.rand(side, side).to(dtype)
    b = torch.rand(side, side).to(dtype)
    for _ in range(3):
        torch.mm(a, b)
    sync()
    done, start = 0, time.perf_counter()
    while done == 0 or time.perf_counter() - start < seconds:
        torch.mm(a, b)
        done += 1
        if done % 16 == 0:
            sync()
    sync()
    return done * 2.0 * side**3 / (time.perf_counter() - start) / 1e9


if __name__ == "__main__":
    main()
