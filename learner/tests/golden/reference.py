#!/usr/bin/env python3
"""Independent reference for dvnav's SAC golden-value tests (learner/tests/sac/golden.rs).

Recomputes, in float64 NumPy with its own small reverse-mode autodiff (checked against central
finite differences below), what the Rust learner computes in float32 with candle:

  * the tanh-squashed Gaussian log-probability (written the direct way,
    log N(u; mu, sigma) - log(1 - tanh(u)^2), not the stable identity the Rust code uses),
  * each SAC loss and its gradients (soft Bellman target, critic loss, actor loss with the L2
    term, temperature loss, Polyak averaging),
  * three full SAC updates (critics, delayed policy and alpha, Polyak) of a tiny navigation
    network: 12 beams, Conv1d(1->3, k4, s2) -> Conv1d(3->2, k2, s1) -> 8 -> 5 -> [goal, v, w
    (, action)] -> 6 -> 6 -> heads. The convolution here is channels-first with einsum
    (PyTorch's layout); the Rust one is channels-last unfold + matmul, and the flatten before
    the first linear layer is length-major (position, channel), so the reference transposes
    to (batch, length, channel) before flattening.

Weights, inputs and noise come from closed-form formulas that golden.rs repeats, rounded to
float32 first, so both sides start from bit-identical numbers.

Run:  pip install numpy && python3 learner/tests/golden/reference.py
It prints Rust constants; paste them into golden.rs.
"""
import numpy as np

f32 = lambda x: np.asarray(x, dtype=np.float32).astype(np.float64)


# ---------------------------------------------------------------- a tiny reverse-mode autodiff
class V:
    def __init__(self, val, parents=(), back=None):
        self.val = np.asarray(val, dtype=np.float64)
        self.parents, self.back, self.grad = parents, back, None

    def __add__(self, o): return add(self, lift(o))
    def __radd__(self, o): return add(lift(o), self)
    def __sub__(self, o): return add(self, neg(lift(o)))
    def __rsub__(self, o): return add(lift(o), neg(self))
    def __mul__(self, o): return mul(self, lift(o))
    def __rmul__(self, o): return mul(lift(o), self)
    def __neg__(self): return neg(self)


def lift(x): return x if isinstance(x, V) else V(x)


def unbroadcast(g, shape):
    while g.ndim > len(shape):
        g = g.sum(0)
    for i, n in enumerate(shape):
        if n == 1 and g.shape[i] != 1:
            g = g.sum(i, keepdims=True)
    return g


def add(a, b): return V(a.val + b.val, (a, b), lambda g: (unbroadcast(g, a.val.shape), unbroadcast(g, b.val.shape)))
def mul(a, b): return V(a.val * b.val, (a, b), lambda g: (unbroadcast(g * b.val, a.val.shape), unbroadcast(g * a.val, b.val.shape)))
def neg(a): return V(-a.val, (a,), lambda g: (-g,))
def exp(a): e = np.exp(a.val); return V(e, (a,), lambda g: (g * e,))
def log(a): return V(np.log(a.val), (a,), lambda g: (g / a.val,))
def tanh(a): t = np.tanh(a.val); return V(t, (a,), lambda g: (g * (1 - t * t),))
def relu(a): return V(np.maximum(a.val, 0), (a,), lambda g: (g * (a.val > 0),))
def leaky_relu(a): return V(np.where(a.val > 0, a.val, 0.01 * a.val), (a,), lambda g: (g * np.where(a.val > 0, 1.0, 0.01),))
def clamp_min(a, lo): return V(np.maximum(a.val, lo), (a,), lambda g: (g * (a.val > lo),))
def recip(a): return V(1 / a.val, (a,), lambda g: (-g / a.val ** 2,))
def square(a): return V(a.val ** 2, (a,), lambda g: (2 * g * a.val,))
def minimum(a, b): return V(np.minimum(a.val, b.val), (a, b), lambda g: (g * (a.val < b.val), g * (a.val >= b.val)))
def sum_all(a): return V(a.val.sum(), (a,), lambda g: (g * np.ones_like(a.val),))
def mean_all(a): return V(a.val.mean(), (a,), lambda g: (g * np.ones_like(a.val) / a.val.size,))
def sum_last(a): return V(a.val.sum(-1), (a,), lambda g: (np.repeat(g[..., None], a.val.shape[-1], -1),))
def cols(a, start, n): 
    def back(g):
        full = np.zeros_like(a.val); full[:, start:start + n] = g; return (full,)
    return V(a.val[:, start:start + n], (a,), back)
def concat(*xs):
    widths = np.cumsum([0] + [x.val.shape[1] for x in xs])
    return V(np.concatenate([x.val for x in xs], 1), xs,
             lambda g: tuple(g[:, widths[i]:widths[i + 1]] for i in range(len(xs))))
def linear(x, w, b):  # x (B, in), w (out, in), b (out,)
    return V(x.val @ w.val.T + b.val, (x, w, b), lambda g: (g @ w.val, g.T @ x.val, g.sum(0)))
def conv1d(x, w, b, stride):  # x (B, C, L), w (O, C, K): channels-first, as PyTorch
    K = w.val.shape[2]; L = x.val.shape[2]; L_out = (L - K) // stride + 1
    idx = np.arange(L_out)[:, None] * stride + np.arange(K)[None, :]
    unf = x.val[:, :, idx]  # (B, C, L_out, K)
    out = np.einsum('bcjk,ock->boj', unf, w.val) + b.val[None, :, None]
    def back(g):
        gx = np.zeros_like(x.val)
        np.add.at(gx, (slice(None), slice(None), idx), np.einsum('boj,ock->bcjk', g, w.val))
        return gx, np.einsum('boj,bcjk->ock', g, unf), g.sum((0, 2))
    return V(out, (x, w, b), back)
def flatten_length_major(x):  # (B, C, L) -> (B, L*C), position-major like the Rust network
    B, C, L = x.val.shape
    return V(x.val.transpose(0, 2, 1).reshape(B, L * C), (x,),
             lambda g: (g.reshape(B, L, C).transpose(0, 2, 1),))


def backward(out, wrt):
    order, seen = [], set()
    def visit(v):
        if id(v) in seen: return
        seen.add(id(v))
        for p in v.parents: visit(p)
        order.append(v)
    visit(out)
    for v in order: v.grad = np.zeros_like(v.val)
    out.grad = np.ones_like(out.val)
    for v in reversed(order):
        if v.back is not None:
            for p, g in zip(v.parents, v.back(v.grad)):
                p.grad = p.grad + g
    return [w.grad if w.grad is not None else np.zeros_like(w.val) for w in wrt]


# ---------------------------------------------------------------- the SAC pieces
LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0


def squashed_gaussian(mean, log_std, eps):
    std = exp(log_std)
    u = mean + std * eps
    z = (u - mean) * recip(std)
    log_normal = -0.5 * square(z) - log_std - 0.5 * np.log(2 * np.pi)
    log_prob = sum_last(log_normal - log(1.0 - square(tanh(u))))
    return tanh(u), log_prob


def soft_bellman_target(r, d, q1n, q2n, logp_n, alpha, gamma):
    return r + gamma * (1 - d) * (np.minimum(q1n, q2n) - alpha * logp_n)


def critic_loss(q1, q2, y): return mean_all(square(q1 - y)) + mean_all(square(q2 - y))


def actor_loss(logp, q1, q2, alpha, l2, weights):
    loss = mean_all(alpha * logp - minimum(q1, q2))
    for w in weights:
        loss = loss + l2 * sum_all(square(w))
    return loss


def temperature_loss(log_alpha, logp, target_entropy):
    return mean_all(neg(exp(log_alpha) * (logp + target_entropy)))


# ---------------------------------------------------------------- the tiny navigation network
BEAMS, EXTRA, ACT = 12, 4, 2
C1, K1, S1, C2, K2, S2, FEAT, HID = 3, 4, 2, 2, 2, 1, 5, 6
LEN1 = (BEAMS - K1) // S1 + 1
LEN2 = (LEN1 - K2) // S2 + 1


def shapes(critic):
    enc = {'encoder.reciprocal_offset': (1,), 'encoder.conv1.weight': (C1, 1, K1), 'encoder.conv1.bias': (C1,),
           'encoder.conv2.weight': (C2, C1, K2), 'encoder.conv2.bias': (C2,),
           'encoder.fc.weight': (FEAT, LEN2 * C2), 'encoder.fc.bias': (FEAT,)}
    if critic:
        head = {'fc1.weight': (HID, FEAT + EXTRA + ACT), 'fc1.bias': (HID,), 'fc2.weight': (HID, HID),
                'fc2.bias': (HID,), 'q.weight': (1, HID), 'q.bias': (1,)}
    else:
        head = {'fc1.weight': (HID, FEAT + EXTRA), 'fc1.bias': (HID,), 'fc2.weight': (HID, HID), 'fc2.bias': (HID,),
                'mean.weight': (ACT, HID), 'mean.bias': (ACT,), 'log_std.weight': (ACT, HID), 'log_std.bias': (ACT,)}
    return {**enc, **head}


def init(critic, salt):
    """The closed-form weights golden.rs writes: variable k (in name order), element i:
    bound * sin(1.3 i + 0.7 k + 2.1 salt), bound = 1/sqrt(fan_in); the offset a = 0.1 + 0.05 salt."""
    sh = shapes(critic)
    params = {}
    for k, name in enumerate(sorted(sh)):
        dims = sh[name]
        n = int(np.prod(dims))
        if name.endswith('reciprocal_offset'):
            v = np.full(n, 0.1 + 0.05 * salt)
        else:
            wdims = dims if name.endswith('.weight') else sh[name[:-len('bias')] + 'weight']
            bound = 1 / np.sqrt(np.prod(wdims[1:]))
            v = bound * np.sin(1.3 * np.arange(n) + 0.7 * k + 2.1 * salt)
        params[name] = V(f32(v).reshape(dims))
    return params


def encode(p, obs):
    scan, extra = cols(obs, 0, BEAMS), cols(obs, BEAMS, EXTRA)
    x = recip(clamp_min(scan + p['encoder.reciprocal_offset'], 1e-2))
    B = x.val.shape[0]
    x = V(x.val.reshape(B, 1, BEAMS), (x,), lambda g: (g.reshape(B, BEAMS),))
    x = leaky_relu(conv1d(x, p['encoder.conv1.weight'], p['encoder.conv1.bias'], S1))
    x = leaky_relu(conv1d(x, p['encoder.conv2.weight'], p['encoder.conv2.bias'], S2))
    x = leaky_relu(linear(flatten_length_major(x), p['encoder.fc.weight'], p['encoder.fc.bias']))
    return x, extra


def actor(p, obs):
    feat, extra = encode(p, obs)
    h = relu(linear(concat(feat, extra), p['fc1.weight'], p['fc1.bias']))
    h = relu(linear(h, p['fc2.weight'], p['fc2.bias']))
    mean = linear(h, p['mean.weight'], p['mean.bias'])
    log_std = (tanh(linear(h, p['log_std.weight'], p['log_std.bias'])) + 1.0) * (0.5 * (LOG_STD_MAX - LOG_STD_MIN)) + LOG_STD_MIN
    return mean, log_std


def critic(p, obs, act):
    feat, extra = encode(p, obs)
    h = relu(linear(concat(feat, extra, act), p['fc1.weight'], p['fc1.bias']))
    h = relu(linear(h, p['fc2.weight'], p['fc2.bias']))
    q = linear(h, p['q.weight'], p['q.bias'])
    return V(q.val[:, 0], (q,), lambda g: (g[:, None],))


class Adam:  # PyTorch's Adam (no weight decay), which is what learner/src/sac/optim.rs does
    def __init__(self, params, lr):
        self.params, self.lr, self.t = params, lr, 0
        self.m = [np.zeros_like(p.val) for p in params]
        self.v = [np.zeros_like(p.val) for p in params]

    def step(self, grads):
        self.t += 1
        b1, b2, eps = 0.9, 0.999, 1e-8
        for i, (p, g) in enumerate(zip(self.params, grads)):
            self.m[i] = b1 * self.m[i] + (1 - b1) * g
            self.v[i] = b2 * self.v[i] + (1 - b2) * g * g
            denom = np.sqrt(self.v[i] / (1 - b2 ** self.t)) + eps
            p.val = p.val - self.lr * (self.m[i] / (1 - b1 ** self.t)) / denom


# ---------------------------------------------------------------- inputs (golden.rs repeats them)
BATCH = 3
OBS_DIM = BEAMS + EXTRA
GAMMA, TAU, LR, ALPHA0, L2, POLICY_DELAY, STEPS = 0.9, 0.1, 0.01, 0.5, 0.01, 2, 3
TARGET_ENTROPY = -float(ACT)


def observations(phase):
    o = np.zeros((BATCH, OBS_DIM))
    for b in range(BATCH):
        for j in range(BEAMS):
            o[b, j] = 0.5 + 1.5 * (1 + np.sin(0.9 * j + 1.7 * b + phase))
        o[b, BEAMS:] = [1.0 + 0.5 * b + phase, 0.3 - 0.4 * b, 0.2 + 0.1 * phase, -0.1 + 0.2 * b]
    return f32(o)


OBS, NEXT_OBS = observations(0.0), observations(0.5)
ACTIONS = f32(0.8 * np.sin(1.1 * np.arange(BATCH * ACT) + 0.3)).reshape(BATCH, ACT)
REWARDS = f32([0.5, -1.0, 10.0])
TERMINATED = f32([0.0, 1.0, 0.0])


def noise(step):
    i = np.arange(BATCH * ACT)
    return (f32(np.sin(2.3 * i + 0.5 + step)).reshape(BATCH, ACT),
            f32(1.2 * np.cos(1.9 * i + 0.2 + step)).reshape(BATCH, ACT))


def fingerprint(v):
    """sum_i w_i (1 + 0.1 (i mod 7)) over the row-major elements, what golden.rs compares."""
    flat = v.reshape(-1)
    return float(np.sum(flat * (1 + 0.1 * (np.arange(flat.size) % 7))))


def fmt(xs): return ', '.join(f'{x:.10e}' for x in xs)


def full_update():
    nets = {'actor': init(False, 0), 'critic1': init(True, 1), 'critic2': init(True, 2),
            'target1': init(True, 1), 'target2': init(True, 2)}
    log_alpha = V(f32([np.log(ALPHA0)]))
    plist = lambda n: [nets[n][k] for k in sorted(nets[n])]
    critic_params = plist('critic1') + plist('critic2')
    actor_params = plist('actor')
    actor_weights = [nets['actor'][k] for k in sorted(nets['actor']) if k.endswith('.weight')]
    critic_opt, actor_opt, alpha_opt = Adam(critic_params, LR), Adam(actor_params, LR), Adam([log_alpha], LR)
    obs, next_obs, act = V(OBS), V(NEXT_OBS), V(ACTIONS)
    metrics = []
    last_actor_loss = last_entropy = 0.0
    for step in range(STEPS):
        eps_next, eps_pi = noise(step)
        alpha = float(np.exp(log_alpha.val[0]))
        # Critics.
        m, ls = actor(nets['actor'], next_obs)
        a_next, logp_next = squashed_gaussian(m, ls, V(eps_next))
        a_next = V(a_next.val)
        y = soft_bellman_target(REWARDS, TERMINATED, critic(nets['target1'], next_obs, a_next).val,
                                critic(nets['target2'], next_obs, a_next).val, logp_next.val, alpha, GAMMA)
        q1, q2 = critic(nets['critic1'], obs, act), critic(nets['critic2'], obs, act)
        lq = critic_loss(q1, q2, V(y))
        critic_opt.step(backward(lq, critic_params))
        q_mean = float(q1.val.mean())
        # Policy and temperature, every POLICY_DELAY-th update, against the updated critics.
        if step % POLICY_DELAY == 0:
            m, ls = actor(nets['actor'], obs)
            a_pi, logp = squashed_gaussian(m, ls, V(eps_pi))
            lpi = actor_loss(logp, critic(nets['critic1'], obs, a_pi), critic(nets['critic2'], obs, a_pi), alpha, L2, actor_weights)
            actor_opt.step(backward(lpi, actor_params))
            last_actor_loss, last_entropy = float(lpi.val), -float(logp.val.mean())
            la = temperature_loss(log_alpha, V(logp.val), TARGET_ENTROPY)
            alpha_opt.step(backward(la, [log_alpha]))
        # Polyak.
        for t, o in (('target1', 'critic1'), ('target2', 'critic2')):
            for k in nets[t]:
                nets[t][k].val = TAU * nets[o][k].val + (1 - TAU) * nets[t][k].val
        metrics.append([float(lq.val), last_actor_loss, float(np.exp(log_alpha.val[0])), q_mean, last_entropy])
    prints = []
    for n in ('actor', 'critic1', 'critic2', 'target1', 'target2'):
        for k in sorted(nets[n]):
            prints.append((f'{n}.{k}', fingerprint(nets[n][k].val)))
    prints.append(('log_alpha', fingerprint(log_alpha.val)))
    return metrics, prints


def finite_difference_check():
    """The autodiff against central differences on the critic and the actor loss."""
    rng = np.random.default_rng(0)
    pa, pc = init(False, 0), init(True, 1)
    obs = V(OBS)
    eps = V(noise(0)[1])

    def loss():
        m, ls = actor(pa, obs)
        a, logp = squashed_gaussian(m, ls, eps)
        q = critic(pc, obs, a)
        return actor_loss(logp, q, q, 0.3, L2, [pa['fc1.weight']]) + critic_loss(q, q, V(np.ones(BATCH)))

    params = list(pa.values()) + list(pc.values())
    grads = backward(loss(), params)
    worst = 0.0
    for p, g in zip(params, grads):
        for _ in range(3):
            i = tuple(rng.integers(0, s) for s in p.val.shape)
            old = p.val[i]
            h = 1e-6
            p.val[i] = old + h; up = loss().val
            p.val[i] = old - h; down = loss().val
            p.val[i] = old
            fd = (up - down) / (2 * h)
            worst = max(worst, abs(fd - g[i]) / max(1e-6, abs(fd) + abs(g[i])))
    assert worst < 1e-5, worst
    return worst


def main():
    print(f'// finite-difference check of the reference autodiff: worst relative error {finite_difference_check():.1e}')

    # tanh-squashed Gaussian: the last row has u = 8, where 1 - tanh(u)^2 ~ 5e-7.
    mean = f32([[0.3, -1.2], [0.0, 2.5], [6.0, -0.4]])
    log_std = f32([[-0.5, 0.2], [-3.0, 1.0], [0.0, -1.5]])
    eps = f32([[0.7, -1.1], [2.0, 0.3], [2.0, 0.9]])
    a, lp = squashed_gaussian(V(mean), V(log_std), V(eps))
    print('// squashed_gaussian')
    print(f'const SQUASH_ACTION: [f64; 6] = [{fmt(a.val.reshape(-1))}];')
    print(f'const SQUASH_LOG_PROB: [f64; 3] = [{fmt(lp.val)}];')

    r, d = f32([1.0, -0.5, 10.0, 0.25]), f32([0.0, 1.0, 0.0, 0.0])
    q1n, q2n = f32([2.0, 3.0, -1.0, 0.7]), f32([2.5, 1.0, -2.0, 0.6])
    lpn = f32([-1.5, 0.3, 2.0, -0.2])
    y = soft_bellman_target(r, d, q1n, q2n, lpn, 0.2, 0.99)
    print('// soft_bellman_target, alpha 0.2, gamma 0.99')
    print(f'const TARGET_Y: [f64; 4] = [{fmt(y)}];')

    q1, q2 = V(f32([1.0, -2.0, 0.5, 3.0])), V(f32([0.5, -1.0, 1.5, 2.0]))
    yv = V(f32([0.8, -1.5, 1.0, 2.5]))
    lq = critic_loss(q1, q2, yv)
    g1, g2 = backward(lq, [q1, q2])
    print('// critic_loss and its gradient in q1 and q2')
    print(f'const CRITIC_LOSS: f64 = {lq.val:.10e};')
    print(f'const CRITIC_GRAD_Q1: [f64; 4] = [{fmt(g1)}];')
    print(f'const CRITIC_GRAD_Q2: [f64; 4] = [{fmt(g2)}];')

    logp = V(f32([-1.0, 0.5, -2.0, 0.1]))
    w1, w2 = V(f32([[0.5, -1.0], [2.0, 0.25]])), V(f32([-0.3, 0.7, 1.1]))
    lpi = actor_loss(logp, q1, q2, 0.3, 0.01, [w1, w2])
    glp, gq1, gw1 = backward(lpi, [logp, q1, w1])
    print('// actor_loss, alpha 0.3, l2 0.01, and its gradient in log pi, q1 and the first weight')
    print(f'const ACTOR_LOSS: f64 = {lpi.val:.10e};')
    print(f'const ACTOR_GRAD_LOG_PROB: [f64; 4] = [{fmt(glp)}];')
    print(f'const ACTOR_GRAD_Q1: [f64; 4] = [{fmt(gq1)}];')
    print(f'const ACTOR_GRAD_W1: [f64; 4] = [{fmt(gw1.reshape(-1))}];')

    la = V(f32([np.log(0.7)]))
    jl = temperature_loss(la, V(logp.val), -2.0)
    (gla,) = backward(jl, [la])
    print('// temperature_loss, alpha 0.7, target entropy -2, and its gradient in log alpha')
    print(f'const TEMPERATURE_LOSS: f64 = {jl.val:.10e};')
    print(f'const TEMPERATURE_GRAD: f64 = {gla[0]:.10e};')

    tgt, onl = f32([1.0, -2.0, 0.5]), f32([0.0, 4.0, 0.25])
    print('// soft_update, tau 0.005')
    print(f'const POLYAK: [f64; 3] = [{fmt(0.005 * onl + 0.995 * tgt)}];')

    metrics, prints = full_update()
    print(f'// {STEPS} full updates of the tiny network: critic_loss, actor_loss, alpha, q_mean, entropy')
    print(f'const UPDATE_METRICS: [[f64; 5]; {STEPS}] = [')
    for m in metrics:
        print(f'    [{fmt(m)}],')
    print('];')
    print('// fingerprints of every variable after the updates')
    print(f'const FINGERPRINTS: [(&str, f64); {len(prints)}] = [')
    for n, v in prints:
        print(f'    ("{n}", {v:.10e}),')
    print('];')


if __name__ == '__main__':
    main()
