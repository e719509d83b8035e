//! Observation transfer and policy transfer (design §5, the paper's DVST equations).
//!
//! The varied robot sees the world through its dimension-scaled robot (DSR), which is the meta
//! robot scaled by μ. Divide every length it observes by μ and the meta agent sees a world in
//! which it is the DSR's size relative to the obstacles; multiply the meta agent's linear
//! velocity by μ and the DSR follows the meta agent's arc scaled by μ (angular velocity and
//! the arc's angle are unchanged by scaling).

use crate::obs::{GOAL_DISTANCE, LINEAR_VELOCITY, obs_dim};

/// A robot's velocity bounds: |v| ≤ `v_max`, |ω| ≤ `omega_max`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct VelocityBounds {
    /// Linear speed bound (m/s), positive.
    pub v_max: f64,
    /// Angular speed bound (rad/s), positive.
    pub omega_max: f64,
}

impl VelocityBounds {
    /// Checks that both bounds are finite and positive.
    pub fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.v_max.is_finite() && self.v_max > 0.0,
            "v_max must be positive, got {}",
            self.v_max
        );
        anyhow::ensure!(
            self.omega_max.is_finite() && self.omega_max > 0.0,
            "omega_max must be positive, got {}",
            self.omega_max
        );
        Ok(())
    }
}

/// Observation transfer: s_m = {s_s^d / μ, s_s^di}. Writes into `out` the observation the meta
/// agent gets for the varied robot's observation `obs` (layout of [`crate::obs`], `beams`
/// ranges): the scan, the goal distance and v divided by `mu`; the goal angle and ω unchanged.
///
/// `scan_range` is the meta agent's LiDAR range `[min, max]` (m), if known. Scaled ranges are
/// clamped to it, so the meta agent gets what its own LiDAR would report in the scaled world,
/// never a value it could not have seen in training. This matters for μ < 1: a beam with no
/// return reads `range_max`, and `range_max / μ` lies beyond anything the meta LiDAR reports
/// (for it, "no return" is `range_max`). For μ > 1 only ranges below μ·`range_min` change,
/// i.e. obstacles already inside the scaled robot. Without it the paper's plain division.
///
/// # Panics
/// If `obs` or `out` is not `obs_dim(beams)` long.
pub fn transfer_observation(
    obs: &[f32],
    beams: usize,
    mu: f64,
    scan_range: Option<[f64; 2]>,
    out: &mut [f32],
) {
    let d = obs_dim(beams);
    assert_eq!(obs.len(), d, "observation length");
    assert_eq!(out.len(), d, "output length");
    out.copy_from_slice(obs);
    transfer_observation_in_place(out, beams, mu, scan_range);
}

/// [`transfer_observation`] over the observation itself: how the simulator shows a varied
/// robot's observation to the meta agent in training (`env.dvst`) without a second buffer.
///
/// # Panics
/// If `obs` is not `obs_dim(beams)` long.
pub fn transfer_observation_in_place(
    obs: &mut [f32],
    beams: usize,
    mu: f64,
    scan_range: Option<[f64; 2]>,
) {
    assert_eq!(obs.len(), obs_dim(beams), "observation length");
    let mu = mu as f32;
    let (lo, hi) =
        scan_range.map_or((f32::NEG_INFINITY, f32::INFINITY), |[lo, hi]| (lo as f32, hi as f32));
    for r in &mut obs[..beams] {
        *r = (*r / mu).clamp(lo, hi);
    }
    // The goal angle and ω are angles: scaling leaves them.
    obs[beams + GOAL_DISTANCE] /= mu;
    obs[beams + LINEAR_VELOCITY] /= mu;
}

/// Policy transfer: the varied robot's command (v_s, ω_s) from the meta agent's (v_m, ω_m) on
/// the transferred observation, for scale `mu` and the varied robot's own `bounds`.
///
/// The ideal command follows the meta arc scaled by μ: v_ideal = μ·v_m, ω_ideal = ω_m,
/// ρ = v_ideal/ω_ideal. Within the bounds the longest arc with curvature ρ that is no longer
/// than the ideal one is (the paper's eqs. vel1 and vel2):
///
/// - if v_max/ω_max ≤ |ρ|: v = min(v_ideal, v_max), ω = v/ρ;
/// - else: ω = sgn(ω_ideal)·min(ω_max, |ω_ideal|), v = ω·ρ;
/// - ω_m = 0 (ρ = ∞, a straight line): v = min(v_ideal, v_max), ω = 0;
/// - v_m = 0 (ρ = 0, turning in place): v = 0, ω = sgn(ω_m)·min(ω_max, |ω_m|).
///
/// Equivalently (v, ω) = k·(v_ideal, ω_ideal) with k = min(1, v_max/|v_ideal|,
/// ω_max/|ω_ideal|): the same arc, shortened. v = ω·ρ is computed as v_ideal·(ω/ω_ideal) (and
/// ω = v/ρ as ω_ideal·(v/v_ideal)), so that for μ = 1 within the bounds the command is the
/// meta command bit for bit. A negative v (a policy that reverses) is bounded by |v| ≤ v_max
/// and keeps its sign; the paper's policies never reverse.
pub fn transfer_policy(v_m: f64, omega_m: f64, mu: f64, bounds: VelocityBounds) -> (f64, f64) {
    let VelocityBounds { v_max, omega_max } = bounds;
    let v_ideal = mu * v_m;
    let omega_ideal = omega_m;
    let limit_v = |v: f64| v.signum() * v.abs().min(v_max);
    let limit_omega = |w: f64| w.signum() * w.abs().min(omega_max);
    if omega_ideal == 0.0 {
        return (limit_v(v_ideal), 0.0);
    }
    if v_ideal == 0.0 {
        return (0.0, limit_omega(omega_ideal));
    }
    // v_max/ω_max ≤ |ρ|, i.e. v_max·|ω_ideal| ≤ ω_max·|v_ideal|, without dividing.
    let (v, omega) = if v_max * omega_ideal.abs() <= omega_max * v_ideal.abs() {
        let v = limit_v(v_ideal);
        (v, omega_ideal * (v / v_ideal))
    } else {
        let omega = limit_omega(omega_ideal);
        (v_ideal * (omega / omega_ideal), omega)
    };
    // The branch condition keeps the other velocity within its bound; the clamp only absorbs
    // the last bit of rounding.
    (v.clamp(-v_max, v_max), omega.clamp(-omega_max, omega_max))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64;

    const META: VelocityBounds =
        VelocityBounds { v_max: 0.5, omega_max: std::f64::consts::FRAC_PI_2 };

    #[test]
    fn straight_line_and_turn_in_place() {
        // ω_m = 0: straight, v limited by v_max, ω stays exactly 0.
        assert_eq!(transfer_policy(0.4, 0.0, 2.0, META), (0.5, 0.0));
        assert_eq!(transfer_policy(0.2, 0.0, 2.0, META), (0.4, 0.0));
        assert_eq!(transfer_policy(0.4, 0.0, 0.5, META), (0.2, 0.0));
        // v_m = 0: turn in place, whatever μ; ω limited by ω_max with its sign.
        assert_eq!(transfer_policy(0.0, 1.0, 3.0, META), (0.0, 1.0));
        assert_eq!(transfer_policy(0.0, -3.0, 3.0, META), (0.0, -META.omega_max));
        assert_eq!(transfer_policy(0.0, 0.0, 3.0, META), (0.0, 0.0));
        // The two branches: a wide arc limited by v_max, a tight one limited by ω_max.
        let (v, w) = transfer_policy(0.5, 0.5, 2.0, META); // ρ = 2 ≥ v_max/ω_max ≈ 0.32
        assert!((v - 0.5).abs() < 1e-15 && (w - 0.25).abs() < 1e-15, "{v} {w}");
        let (v, w) = transfer_policy(0.1, -1.5, 2.0, VelocityBounds { v_max: 0.5, omega_max: 1.0 });
        assert!((w + 1.0).abs() < 1e-15 && (v - 0.2 / 1.5).abs() < 1e-15, "{v} {w}");
    }

    /// Properties over many random commands, scales and bounds: the commanded arc has the ideal
    /// curvature, is no longer than the ideal arc and turns no more, stays inside the bounds,
    /// and is as long as the bounds allow (one of them is tight, or it is the ideal arc).
    #[test]
    fn commanded_arc_keeps_the_curvature_within_the_bounds() {
        let mut rng = Pcg64::seed_from_u64(5);
        for case in 0..20_000 {
            let bounds = VelocityBounds {
                v_max: rng.random_range(0.05..2.0),
                omega_max: rng.random_range(0.1..4.0),
            };
            let mu = rng.random_range(0.2..6.0);
            let v_m = if rng.random_bool(0.05) { 0.0 } else { rng.random_range(-0.3..1.5) };
            let w_m = if rng.random_bool(0.05) { 0.0 } else { rng.random_range(-3.0..3.0) };
            let (v, w) = transfer_policy(v_m, w_m, mu, bounds);
            let (vi, wi) = (mu * v_m, w_m);
            let ctx = format!("case {case}: m=({v_m}, {w_m}) mu={mu} {bounds:?} -> ({v}, {w})");
            assert!(v.abs() <= bounds.v_max && w.abs() <= bounds.omega_max, "bounds: {ctx}");
            assert!(v.abs() <= vi.abs() && w.abs() <= wi.abs(), "longer than ideal: {ctx}");
            // Same curvature: v·ω_ideal = ω·v_ideal (also covers ρ = 0 and ρ = ∞), same way.
            let scale = vi.abs().max(1e-300) * wi.abs().max(1e-300);
            assert!((v * wi - w * vi).abs() <= 1e-12 * scale, "curvature: {ctx}");
            assert!(v * vi >= 0.0 && w * wi >= 0.0, "direction: {ctx}");
            // Longest: the ideal arc, or one bound reached (up to rounding).
            let tight = (v.abs() - vi.abs()).abs() < 1e-12 && (w.abs() - wi.abs()).abs() < 1e-12
                || (v.abs() - bounds.v_max).abs() < 1e-12
                || (w.abs() - bounds.omega_max).abs() < 1e-12;
            assert!(tight, "not the longest arc: {ctx}");
            // The uniform-shortening form gives the same command.
            let mut k: f64 = 1.0;
            if vi != 0.0 {
                k = k.min(bounds.v_max / vi.abs());
            }
            if wi != 0.0 {
                k = k.min(bounds.omega_max / wi.abs());
            }
            assert!((v - k * vi).abs() < 1e-12 && (w - k * wi).abs() < 1e-12, "k-form: {ctx}");
        }
    }

    /// μ = 1 with the meta robot's bounds: the meta command passes unchanged, bit for bit.
    #[test]
    fn identity_for_mu_one_within_the_meta_bounds() {
        let mut rng = Pcg64::seed_from_u64(1);
        for _ in 0..20_000 {
            let v = if rng.random_bool(0.05) { 0.0 } else { rng.random_range(0.0..=META.v_max) };
            let w = if rng.random_bool(0.05) {
                0.0
            } else {
                rng.random_range(-META.omega_max..=META.omega_max)
            };
            assert_eq!(transfer_policy(v, w, 1.0, META), (v, w));
        }
    }

    #[test]
    fn observation_scales_lengths_and_keeps_angles() {
        let beams = 4;
        let obs = [0.5, 1.0, 10.0, 0.03, 3.0, -0.7, 0.4, 1.2];
        let mut out = [0.0f32; 8];
        transfer_observation(&obs, beams, 2.0, None, &mut out);
        assert_eq!(out, [0.25, 0.5, 5.0, 0.015, 1.5, -0.7, 0.2, 1.2]);
        transfer_observation(&obs, beams, 2.0, Some([0.02, 10.0]), &mut out);
        assert_eq!(out[..4], [0.25, 0.5, 5.0, 0.02], "floored at the meta range_min");
        transfer_observation(&obs, beams, 0.5, Some([0.02, 10.0]), &mut out);
        assert_eq!(out, [1.0, 2.0, 10.0, 0.06, 6.0, -0.7, 0.8, 1.2], "no return stays range_max");
        transfer_observation(&obs, beams, 1.0, Some([0.02, 10.0]), &mut out);
        assert_eq!(out, obs, "identity for mu = 1");
    }
}
