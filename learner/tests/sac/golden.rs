//! Golden values: the tanh-squashed Gaussian log-probability, each SAC loss (with its
//! gradients) and three full SAC updates of a tiny navigation network, against numbers from an
//! independent float64 NumPy reference, `learner/tests/golden/reference.py` (its own autodiff,
//! checked by finite differences; channels-first convolutions). The constants below are what
//! that script printed; rerun it to regenerate them (`pip install numpy`; CI needs no Python).
//!
//! Weights, inputs and noise are closed-form formulas both sides evaluate and round to f32, so
//! both start from the same bits. Tolerances (relative to max(1, |expected|)) allow for float32
//! arithmetic against float64: 1e-6 for single functions, 1e-5 for the full updates (the largest
//! differences measured were 1e-7 and 2.2e-7).

use candle_core::{Device, Tensor, Var};
use dvnav_config::{Config, Precision, SacConfig};
use dvnav_learner::replay::Batch;
use dvnav_learner::sac::learning::{
    UpdateNoise, actor_loss, critic_loss, soft_bellman_target, soft_update, temperature_loss,
};
use dvnav_learner::sac::networks::Owned;
use dvnav_learner::sac::{SacLearner, SacNetworks};
use dvnav_nav::nets::squashed_gaussian;

/// Tolerance of single functions, relative to max(1, |expected|).
const TOL_FUNCTION: f64 = 1e-6;
/// Tolerance of values after three full updates.
const TOL_UPDATE: f64 = 1e-5;
/// Tolerance of the updates' metrics in bf16 mode (largest difference measured: 1.3e-3).
const TOL_BF16_METRICS: f64 = 5e-3;
/// Tolerance of the variables' fingerprints after three updates in bf16 mode (largest
/// difference measured: 9.0e-3). Adam's first steps are about lr·sign(g) per element, so an
/// element whose gradient lies within bf16 rounding of zero may step the other way: 2·lr =
/// 0.02 per update for that element. The gradients themselves are compared more tightly in
/// `dvnav_nav::nets` (`gradients_in_bf16_follow_fp32`).
const TOL_BF16_VARS: f64 = 3e-2;

// ---- Printed by learner/tests/golden/reference.py ----
// finite-difference check of the reference autodiff: worst relative error 3.1e-06
// squashed_gaussian
const SQUASH_ACTION: [f64; 6] = [
    6.1973299098e-01,
    -9.8772383922e-01,
    9.9246343891e-02,
    9.9736570582e-01,
    9.9999977493e-01,
    -1.9658989393e-01,
];
const SQUASH_LOG_PROB: [f64; 3] = [1.8098490753e+00, 3.3743324287e+00, 1.1910243040e+01];
// soft_bellman_target, alpha 0.2, gamma 0.99
const TARGET_Y: [f64; 4] =
    [3.2770000000e+00, -5.0000000000e-01, 7.6240000000e+00, 8.8360002419e-01];
// critic_loss and its gradient in q1 and q2
const CRITIC_LOSS: f64 = 4.0750000060e-01;
const CRITIC_GRAD_Q1: [f64; 4] =
    [9.9999994040e-02, -2.5000000000e-01, -2.5000000000e-01, 2.5000000000e-01];
const CRITIC_GRAD_Q2: [f64; 4] =
    [-1.5000000596e-01, 2.5000000000e-01, 2.5000000000e-01, -2.5000000000e-01];
// actor_loss, alpha 0.3, l2 0.01, and its gradient in log pi, q1 and the first weight
const ACTOR_LOSS: f64 = -3.5897499946e-01;
const ACTOR_GRAD_LOG_PROB: [f64; 4] =
    [7.5000000000e-02, 7.5000000000e-02, 7.5000000000e-02, 7.5000000000e-02];
const ACTOR_GRAD_Q1: [f64; 4] =
    [0.0000000000e+00, -2.5000000000e-01, -2.5000000000e-01, 0.0000000000e+00];
const ACTOR_GRAD_W1: [f64; 4] =
    [1.0000000000e-02, -2.0000000000e-02, 4.0000000000e-02, 5.0000000000e-03];
// temperature_loss, alpha 0.7, target entropy -2, and its gradient in log alpha
const TEMPERATURE_LOSS: f64 = 1.8200000080e+00;
const TEMPERATURE_GRAD: f64 = 1.8200000080e+00;
// soft_update, tau 0.005
const POLYAK: [f64; 3] = [9.9500000000e-01, -1.9700000000e+00, 4.9875000000e-01];
// 3 full updates of the tiny network: critic_loss, actor_loss, alpha, q_mean, entropy
const UPDATE_METRICS: [[f64; 5]; 3] = [
    [6.0286363550e+01, 4.7864901267e-01, 4.9502491598e-01, -2.5781874515e-01, -1.5357150503e-02],
    [6.1963795706e+01, 4.7864901267e-01, 4.9502491598e-01, -1.9114500241e-01, -1.5357150503e-02],
    [6.3645079268e+01, 3.6337946678e-01, 4.9009725402e-01, -1.3591417766e-01, 4.0631175414e-02],
];
// fingerprints of every variable after the updates
const FINGERPRINTS: [(&str, f64); 68] = [
    ("actor.encoder.conv1.bias", 8.2228470581e-01),
    ("actor.encoder.conv1.weight", 1.2194490317e+00),
    ("actor.encoder.conv2.bias", 5.5451140390e-01),
    ("actor.encoder.conv2.weight", 1.1676674855e-01),
    ("actor.encoder.fc.bias", 1.3078807104e-01),
    ("actor.encoder.fc.weight", -5.4050434113e-01),
    ("actor.encoder.reciprocal_offset", 1.1233481650e-01),
    ("actor.fc1.bias", -5.3105450140e-01),
    ("actor.fc1.weight", -4.4640388457e-01),
    ("actor.fc2.bias", -1.1840379726e-01),
    ("actor.fc2.weight", 5.0333864296e-01),
    ("actor.log_std.bias", 6.3016931164e-01),
    ("actor.log_std.weight", 2.9221762602e-01),
    ("actor.mean.bias", -2.2574267118e-01),
    ("actor.mean.weight", -8.5407261813e-01),
    ("critic1.encoder.conv1.bias", -2.8844228806e-01),
    ("critic1.encoder.conv1.weight", -6.5179568923e-01),
    ("critic1.encoder.conv2.bias", -5.8740545960e-01),
    ("critic1.encoder.conv2.weight", -9.0817329786e-01),
    ("critic1.encoder.fc.bias", 8.2501240613e-03),
    ("critic1.encoder.fc.weight", -5.9525074647e-01),
    ("critic1.encoder.reciprocal_offset", 1.7741310410e-01),
    ("critic1.fc1.bias", 3.4657690104e-01),
    ("critic1.fc1.weight", -5.8539066317e-02),
    ("critic1.fc2.bias", 5.3698136704e-01),
    ("critic1.fc2.weight", -2.9595286312e-01),
    ("critic1.q.bias", -1.1960194129e-01),
    ("critic1.q.weight", -3.4852176224e-01),
    ("critic2.encoder.conv1.bias", -4.9520539148e-01),
    ("critic2.encoder.conv1.weight", -5.3616929563e-01),
    ("critic2.encoder.conv2.bias", 5.9029665659e-03),
    ("critic2.encoder.conv2.weight", 7.9638893430e-01),
    ("critic2.encoder.fc.bias", -1.2626774213e-01),
    ("critic2.encoder.fc.weight", 6.9694692634e-01),
    ("critic2.encoder.reciprocal_offset", 1.7043893489e-01),
    ("critic2.fc1.bias", 1.5246445714e-01),
    ("critic2.fc1.weight", -4.5802123294e-01),
    ("critic2.fc2.bias", -5.2639480092e-01),
    ("critic2.fc2.weight", -6.1857569269e-01),
    ("critic2.q.bias", -2.2233741497e-01),
    ("critic2.q.weight", 7.2116805537e-02),
    ("target1.encoder.conv1.bias", -3.0467266599e-01),
    ("target1.encoder.conv1.weight", -6.1557458933e-01),
    ("target1.encoder.conv2.bias", -5.8998806910e-01),
    ("target1.encoder.conv2.weight", -9.6855259945e-01),
    ("target1.encoder.fc.bias", -1.5593142807e-02),
    ("target1.encoder.fc.weight", -4.4123325776e-01),
    ("target1.encoder.reciprocal_offset", 1.5527516774e-01),
    ("target1.fc1.bias", 2.7504445202e-01),
    ("target1.fc1.weight", 7.1529531181e-02),
    ("target1.fc2.bias", 5.3195016997e-01),
    ("target1.fc2.weight", -2.6282387864e-01),
    ("target1.q.bias", -1.4400290597e-01),
    ("target1.q.weight", -4.6545046675e-01),
    ("target2.encoder.conv1.bias", -5.2132718376e-01),
    ("target2.encoder.conv1.weight", -6.3359996768e-01),
    ("target2.encoder.conv2.bias", 2.7336940673e-03),
    ("target2.encoder.conv2.weight", 7.8534025106e-01),
    ("target2.encoder.fc.bias", -1.2404874885e-01),
    ("target2.encoder.fc.weight", 6.8153528537e-01),
    ("target2.encoder.reciprocal_offset", 1.9445935225e-01),
    ("target2.fc1.bias", 1.7119814334e-01),
    ("target2.fc1.weight", -4.5351749988e-01),
    ("target2.fc2.bias", -4.9989194365e-01),
    ("target2.fc2.weight", -5.3290050673e-01),
    ("target2.q.bias", -2.4674141706e-01),
    ("target2.q.weight", -1.2854367696e-02),
    ("log_alpha", -7.1315142999e-01),
];
// ---- End of the script's output ----

fn assert_close(what: &str, got: &[f64], want: &[f64], tol: f64) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        let err = (g - w).abs() / w.abs().max(1.0);
        assert!(
            err <= tol,
            "{what}[{i}]: got {g:.9e}, reference {w:.9e} (error {err:.1e} > {tol:.0e})"
        );
    }
}

fn dev() -> Device {
    Device::Cpu
}

fn t(v: &[f32]) -> Tensor {
    Tensor::new(v, &dev()).unwrap()
}

fn values(t: &Tensor) -> Vec<f64> {
    t.flatten_all().unwrap().to_dtype(candle_core::DType::F64).unwrap().to_vec1().unwrap()
}

#[test]
fn squashed_gaussian_log_prob_matches_the_reference() {
    let mean = Tensor::new(&[[0.3f32, -1.2], [0.0, 2.5], [6.0, -0.4]], &dev()).unwrap();
    let log_std = Tensor::new(&[[-0.5f32, 0.2], [-3.0, 1.0], [0.0, -1.5]], &dev()).unwrap();
    let eps = Tensor::new(&[[0.7f32, -1.1], [2.0, 0.3], [2.0, 0.9]], &dev()).unwrap();
    let s = squashed_gaussian(&mean, &log_std, &eps).unwrap();
    assert_close("action", &values(&s.action), &SQUASH_ACTION, TOL_FUNCTION);
    assert_close("log_prob", &values(&s.log_prob), &SQUASH_LOG_PROB, TOL_FUNCTION);
}

#[test]
fn soft_bellman_target_matches_the_reference() {
    let y = soft_bellman_target(
        &t(&[1.0, -0.5, 10.0, 0.25]),
        &t(&[0.0, 1.0, 0.0, 0.0]),
        &t(&[0.99; 4]),
        &t(&[2.0, 3.0, -1.0, 0.7]),
        &t(&[2.5, 1.0, -2.0, 0.6]),
        &t(&[-1.5, 0.3, 2.0, -0.2]),
        &0.2,
    )
    .unwrap();
    assert_close("y", &values(&y), &TARGET_Y, TOL_FUNCTION);
}

#[test]
fn critic_loss_and_its_gradients_match_the_reference() {
    let q1 = Var::new(&[1.0f32, -2.0, 0.5, 3.0], &dev()).unwrap();
    let q2 = Var::new(&[0.5f32, -1.0, 1.5, 2.0], &dev()).unwrap();
    let loss = critic_loss(q1.as_tensor(), q2.as_tensor(), &t(&[0.8, -1.5, 1.0, 2.5])).unwrap();
    assert_close("critic_loss", &values(&loss), &[CRITIC_LOSS], TOL_FUNCTION);
    let grads = loss.backward().unwrap();
    assert_close("dL/dq1", &values(grads.get(&q1).unwrap()), &CRITIC_GRAD_Q1, TOL_FUNCTION);
    assert_close("dL/dq2", &values(grads.get(&q2).unwrap()), &CRITIC_GRAD_Q2, TOL_FUNCTION);
}

#[test]
fn actor_loss_and_its_gradients_match_the_reference() {
    let log_prob = Var::new(&[-1.0f32, 0.5, -2.0, 0.1], &dev()).unwrap();
    let q1 = Var::new(&[1.0f32, -2.0, 0.5, 3.0], &dev()).unwrap();
    let q2 = t(&[0.5, -1.0, 1.5, 2.0]);
    let w1 = Var::new(&[[0.5f32, -1.0], [2.0, 0.25]], &dev()).unwrap();
    let w2 = t(&[-0.3, 0.7, 1.1]);
    let weights = [w1.as_tensor().clone(), w2];
    let loss = actor_loss(log_prob.as_tensor(), q1.as_tensor(), &q2, &0.3, 0.01, &weights).unwrap();
    assert_close("actor_loss", &values(&loss), &[ACTOR_LOSS], TOL_FUNCTION);
    let grads = loss.backward().unwrap();
    let g = |v: &Var| values(grads.get(v).unwrap());
    assert_close("dL/dlog_prob", &g(&log_prob), &ACTOR_GRAD_LOG_PROB, TOL_FUNCTION);
    assert_close("dL/dq1", &g(&q1), &ACTOR_GRAD_Q1, TOL_FUNCTION);
    assert_close("dL/dw1", &g(&w1), &ACTOR_GRAD_W1, TOL_FUNCTION);
}

#[test]
fn temperature_loss_and_its_gradient_match_the_reference() {
    let log_alpha = Var::new(&[0.7f32.ln()], &dev()).unwrap();
    let log_prob = Var::new(&[-1.0f32, 0.5, -2.0, 0.1], &dev()).unwrap();
    let loss = temperature_loss(log_alpha.as_tensor(), log_prob.as_tensor(), -2.0).unwrap();
    assert_close("J(alpha)", &values(&loss), &[TEMPERATURE_LOSS], TOL_FUNCTION);
    let grads = loss.backward().unwrap();
    assert_close(
        "dJ/dlog_alpha",
        &values(grads.get(&log_alpha).unwrap()),
        &[TEMPERATURE_GRAD],
        TOL_FUNCTION,
    );
    assert!(grads.get(&log_prob).is_none(), "log pi is a constant in J(alpha)");
}

#[test]
fn soft_update_matches_the_reference() {
    let owned = |v: &[f32]| {
        let o =
            Owned::build(&dev(), 0, |vb| vb.get_with_hints(3, "w", candle_nn::Init::Const(0.0)))
                .unwrap();
        o.vars.data().lock().unwrap()["w"].set(&t(v)).unwrap();
        o
    };
    let target = owned(&[1.0, -2.0, 0.5]);
    let online = owned(&[0.0, 4.0, 0.25]);
    soft_update(&target, &online, 0.005).unwrap();
    assert_close("polyak", &values(target.net.as_ref()), &POLYAK, TOL_FUNCTION);
    assert_close("online untouched", &values(online.net.as_ref()), &[0.0, 4.0, 0.25], 0.0);
}

// ---- The tiny network and its inputs, as reference.py defines them ----

const BEAMS: usize = 12;
const BATCH: usize = 3;

/// The tiny navigation network and SAC settings of reference.py (the resume tests use it too).
pub fn tiny_config() -> Config {
    let mut cfg = Config::default();
    cfg.env.lidar.beams = BEAMS;
    let n = &mut cfg.network;
    (n.conv1_channels, n.conv1_kernel, n.conv1_stride) = (3, 4, 2);
    (n.conv2_channels, n.conv2_kernel, n.conv2_stride) = (2, 2, 1);
    (n.scan_features, n.hidden) = (5, 6);
    (n.log_std_min, n.log_std_max) = (-5.0, 2.0);
    cfg.sac = SacConfig {
        gamma: 0.9,
        tau: 0.1,
        actor_lr: 0.01,
        critic_lr: 0.01,
        alpha_lr: 0.01,
        autotune_alpha: true,
        initial_alpha: 0.5,
        target_entropy: None,
        policy_delay: 2,
        policy_l2: 0.01,
        ..SacConfig::default()
    };
    cfg
}

/// Variable k (in name order), element i: bound·sin(1.3 i + 0.7 k + 2.1 salt) with bound =
/// 1/√fan_in of its layer; the reciprocal offset a = 0.1 + 0.05 salt.
fn fill<N>(net: &Owned<N>, salt: f64) {
    let vars = net.named_vars();
    let dims_of = |name: &str| vars.iter().find(|(n, _)| n == name).unwrap().1.dims().to_vec();
    for (k, (name, var)) in vars.iter().enumerate() {
        let dims = var.dims().to_vec();
        let n: usize = dims.iter().product();
        let v: Vec<f32> = if name.ends_with("reciprocal_offset") {
            vec![(0.1 + 0.05 * salt) as f32; n]
        } else {
            let w = if name.ends_with(".weight") {
                dims.clone()
            } else {
                dims_of(&(name.trim_end_matches("bias").to_string() + "weight"))
            };
            let bound = 1.0 / (w[1..].iter().product::<usize>() as f64).sqrt();
            (0..n)
                .map(|i| (bound * (1.3 * i as f64 + 0.7 * k as f64 + 2.1 * salt).sin()) as f32)
                .collect()
        };
        var.set(&Tensor::from_vec(v, dims, &dev()).unwrap()).unwrap();
    }
}

fn observations(phase: f64) -> Vec<f32> {
    let mut o = Vec::new();
    for b in 0..BATCH {
        let bf = b as f64;
        for j in 0..BEAMS {
            o.push((0.5 + 1.5 * (1.0 + (0.9 * j as f64 + 1.7 * bf + phase).sin())) as f32);
        }
        for x in [1.0 + 0.5 * bf + phase, 0.3 - 0.4 * bf, 0.2 + 0.1 * phase, -0.1 + 0.2 * bf] {
            o.push(x as f32);
        }
    }
    o
}

fn noise(step: usize) -> UpdateNoise {
    let s = step as f64;
    UpdateNoise {
        next: (0..BATCH * 2).map(|i| (2.3 * i as f64 + 0.5 + s).sin() as f32).collect(),
        current: (0..BATCH * 2).map(|i| (1.2 * (1.9 * i as f64 + 0.2 + s).cos()) as f32).collect(),
    }
}

/// Σ_i w_i (1 + 0.1 (i mod 7)) over the row-major elements.
fn fingerprint(t: &Tensor) -> f64 {
    values(t).iter().enumerate().map(|(i, w)| w * (1.0 + 0.1 * (i % 7) as f64)).sum()
}

/// Three full updates of the tiny network from reference.py's weights: each update's metrics
/// (critic loss, actor loss, α, mean Q, entropy), then every variable's fingerprint by name.
fn three_full_updates(precision: Precision) -> (Vec<[f64; 5]>, Vec<(String, f64)>) {
    let mut cfg = tiny_config();
    cfg.learner.precision = precision;
    let nets = SacNetworks::new(&cfg, 0, &dev()).unwrap();
    for (net, salt) in
        [(&nets.critic1, 1.0), (&nets.critic2, 2.0), (&nets.target1, 1.0), (&nets.target2, 2.0)]
    {
        fill(net, salt);
    }
    fill(&nets.actor, 0.0);
    let mut learner = SacLearner::new(nets, cfg.sac.clone(), dev(), 0).unwrap();
    let batch = Batch {
        size: BATCH,
        obs_dim: BEAMS + 4,
        obs: observations(0.0),
        next_obs: observations(0.5),
        actions: (0..BATCH * 2).map(|i| (0.8 * (1.1 * i as f64 + 0.3).sin()) as f32).collect(),
        rewards: vec![0.5, -1.0, 10.0],
        discounts: vec![cfg.sac.gamma as f32; 3],
        terminated: vec![0.0, 1.0, 0.0],
        demonstrated: vec![0.0; 3],
    };
    let metrics = (0..UPDATE_METRICS.len())
        .map(|step| {
            let m = learner.update_with_noise(&batch, &noise(step)).unwrap();
            [m.critic_loss, m.actor_loss, m.alpha, m.q_mean, m.entropy]
        })
        .collect();
    let nets = &learner.nets;
    let mut got = Vec::new();
    for (prefix, vars) in [
        ("actor", nets.actor.named_vars()),
        ("critic1", nets.critic1.named_vars()),
        ("critic2", nets.critic2.named_vars()),
        ("target1", nets.target1.named_vars()),
        ("target2", nets.target2.named_vars()),
    ] {
        got.extend(
            vars.into_iter().map(|(n, v)| (format!("{prefix}.{n}"), fingerprint(v.as_tensor()))),
        );
    }
    got.push(("log_alpha".into(), fingerprint(nets.log_alpha.as_tensor())));
    (metrics, got)
}

fn assert_updates_match_the_reference(precision: Precision, tol_metrics: f64, tol_vars: f64) {
    let (metrics, vars) = three_full_updates(precision);
    for (step, (got, want)) in metrics.iter().zip(UPDATE_METRICS.iter()).enumerate() {
        assert_close(&format!("{precision} update {step} metrics"), got, want, tol_metrics);
    }
    assert_eq!(vars.len(), FINGERPRINTS.len());
    for ((name, g), (want_name, w)) in vars.iter().zip(FINGERPRINTS.iter()) {
        assert_eq!(name, want_name);
        assert_close(&format!("{precision} {name}"), &[*g], &[*w], tol_vars);
    }
}

#[test]
fn three_full_updates_match_the_reference() {
    assert_updates_match_the_reference(Precision::Fp32, TOL_UPDATE, TOL_UPDATE);
}

/// bf16 mode (every matrix product, forward and backward, with bf16 operands and fp32 sums)
/// against the same float64 reference: each update's losses, Q and entropy come from
/// bf16-rounded products (relative error ~2^-8 per product), and the variables after three
/// Adam steps of lr 0.01 carry those errors through the gradients.
#[test]
fn three_full_updates_in_bf16_follow_the_reference_within_bf16_tolerance() {
    assert_updates_match_the_reference(Precision::Bf16, TOL_BF16_METRICS, TOL_BF16_VARS);
    // And bf16 mode is not fp32 in disguise: its results differ from the fp32 ones.
    let (m32, _) = three_full_updates(Precision::Fp32);
    let (m16, _) = three_full_updates(Precision::Bf16);
    assert_ne!(m32, m16);
}
