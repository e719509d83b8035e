//! The arithmetic of one SAC update, counted from the network's shapes, so that `dvnav bench
//! learner` can say how close an update runs to the CPU's peak.
//!
//! Convention: a forward pass costs 2 FLOPs per multiply-add of its convolutions and linear
//! layers; a backward pass twice that (the gradient of the input and of the weights). The
//! element-wise work (activations, the loss, Adam) is left out: it is a few percent of the
//! total at these widths, and leaving it out makes the figure a lower bound on the work done.

use dvnav_config::Config;

/// Multiply-adds of one forward pass per sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ForwardMacs {
    /// The policy network (scan encoder, two hidden layers, mean and log-std heads).
    pub actor: f64,
    /// One critic (scan encoder, two hidden layers over [features, extra, action], one head).
    pub critic: f64,
}

/// Length of a valid, unpadded 1D convolution's output.
fn conv_out(len: usize, kernel: usize, stride: usize) -> usize {
    if len < kernel { 0 } else { (len - kernel) / stride + 1 }
}

/// Multiply-adds per sample of each network's forward pass (design §3's layout).
pub fn forward_macs(cfg: &Config) -> ForwardMacs {
    let n = &cfg.network;
    let layout = cfg.obs_layout();
    let len1 = conv_out(layout.beams, n.conv1_kernel, n.conv1_stride);
    let len2 = conv_out(len1, n.conv2_kernel, n.conv2_stride);
    let encoder = len1 * n.conv1_channels * n.conv1_kernel
        + len2 * n.conv2_channels * n.conv1_channels * n.conv2_kernel
        + len2 * n.conv2_channels * n.scan_features;
    let head_in = n.scan_features + layout.extra();
    let body = |inputs: usize| inputs * n.hidden + n.hidden * n.hidden;
    let action = 2;
    ForwardMacs {
        actor: (encoder + body(head_in) + n.hidden * 2 * action) as f64,
        critic: (encoder + body(head_in + action) + n.hidden) as f64,
    }
}

/// FLOPs of one SAC update at `batch`, averaged over `policy_delay` updates (the critics
/// learn every update, the policy every `policy_delay`-th):
/// - the target: the policy forward on s′ and both target critics forward;
/// - the critics: both forward and backward;
/// - the policy step: the policy forward, both critics forward on (s, ã), and the backward
///   through all three (candle's backward reaches the critics' weights too).
pub fn update_flops(cfg: &Config, batch: usize) -> f64 {
    let m = forward_macs(cfg);
    let (fwd, bwd) = (2.0, 4.0);
    let target = fwd * (m.actor + 2.0 * m.critic);
    let critics = (fwd + bwd) * 2.0 * m.critic;
    let policy = (fwd + bwd) * (m.actor + 2.0 * m.critic);
    batch as f64 * (target + critics + policy / cfg.sac.policy_delay.max(1) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_network_counts_match_a_hand_count() {
        // conv1: 105 positions x 32 channels x 20 taps; conv2: 32 x 32 x 32 x 10;
        // fc: 1024 -> 128; hidden: (132 [+2]) -> 256 -> 256; heads 256 -> 4 (actor), -> 1.
        let m = forward_macs(&Config::default());
        let encoder = 105.0 * 32.0 * 20.0 + 32.0 * 32.0 * 32.0 * 10.0 + 1024.0 * 128.0;
        assert_eq!(m.actor, encoder + 132.0 * 256.0 + 256.0 * 256.0 + 256.0 * 4.0);
        assert_eq!(m.critic, encoder + 134.0 * 256.0 + 256.0 * 256.0 + 256.0);
        // ~0.63 M multiply-adds per forward, as the learner-speed issue counted.
        assert!((m.actor / 1e6 - 0.627).abs() < 0.01, "{}", m.actor);
    }

    #[test]
    fn update_flops_scale_with_batch_and_policy_delay() {
        let mut cfg = Config::default();
        let b128 = update_flops(&cfg, 128);
        assert!((update_flops(&cfg, 256) / b128 - 2.0).abs() < 1e-12);
        // 2.5 actor + 11 critic forwards' worth of multiply-adds per sample at delay 2.
        let m = forward_macs(&cfg);
        assert!((b128 - 128.0 * 2.0 * (2.5 * m.actor + 11.0 * m.critic)).abs() < 1.0);
        cfg.sac.policy_delay = 1;
        assert!(update_flops(&cfg, 128) > b128);
    }
}
