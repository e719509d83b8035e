//! What a real robot adds to the simulator's clean world, as configuration (`[env.robustness]`):
//! LiDAR beam dropout, observation latency, actuation noise on (v, ω) and control-period
//! jitter (Gaussian range noise is `[env.lidar] noise_std`). All are 0 by default, which is
//! how `dvnav eval` runs unless asked; `[env.robustness.randomize]` draws them per episode
//! from ranges instead, for training.
//!
//! Each episode's values ([`Perturbation`]) are drawn at its reset from the environment's own
//! robustness generator, apart from the task generator, so switching robustness on or off
//! never changes which starts and goals a seed gives.

use rand::Rng;
use serde::{Deserialize, Serialize};

/// Fixed perturbations (evaluation) and per-episode ranges (training).
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RobustnessConfig {
    /// Share of beams that return nothing in each scan, drawn beam by beam. A dropped beam
    /// reads as `dvnav serve` reads a driver's lost return, half each: `range_max` (+inf or 0
    /// from the driver) or the nearer of its seen neighbours (NaN).
    pub beam_dropout: f64,
    /// Control cycles of observation latency: the policy sees the scan and goal of this many
    /// cycles ago (the reset's until there is one that old) beside the command it last sent.
    pub latency_steps: u32,
    /// Standard deviations of Gaussian noise on the executed command, `[v (m/s), ω (rad/s)]`;
    /// the noisy command is clamped to the velocity bounds again.
    pub actuation_noise_std: [f64; 2],
    /// Control-period jitter: each step lasts `dt·(1 + u)`, u uniform in `[−j, j]`.
    pub dt_jitter: f64,
    /// Per-episode ranges that replace the fixed values above (and `lidar.noise_std`) when
    /// present.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub randomize: Option<RandomizeConfig>,
}

/// `[lo, hi]` ranges drawn uniformly at every episode's reset.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RandomizeConfig {
    /// LiDAR range noise σ (m).
    pub noise_std: [f64; 2],
    /// Beam dropout share.
    pub beam_dropout: [f64; 2],
    /// Latency in whole cycles (both ends included).
    pub latency_steps: [u32; 2],
    /// Scale of `actuation_noise_std` (e.g. `[0, 1]`: from none to the configured σ).
    pub actuation_noise_scale: [f64; 2],
    /// Control-period jitter share.
    pub dt_jitter: [f64; 2],
    /// Share of episodes that draw nothing from these ranges and run clean (LiDAR noise at
    /// `lidar.noise_std`, nothing else perturbed), so that a noise stage keeps rehearsing the
    /// clean skill it builds on. 0 (the default) perturbs every episode.
    #[serde(skip_serializing_if = "is_zero")]
    pub clean_share: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

/// One episode's perturbations.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Perturbation {
    /// LiDAR range noise σ (m).
    pub noise_std: f64,
    /// Beam dropout share.
    pub beam_dropout: f64,
    /// Observation latency (cycles).
    pub latency_steps: u32,
    /// Actuation noise σ, `[v, ω]`.
    pub actuation_noise_std: [f64; 2],
    /// Control-period jitter share.
    pub dt_jitter: f64,
}

impl Perturbation {
    /// The fixed values of `cfg` (with LiDAR noise `noise_std`), or a draw from its ranges.
    pub fn draw(cfg: &RobustnessConfig, noise_std: f64, rng: &mut impl Rng) -> Perturbation {
        let Some(r) = &cfg.randomize else {
            return Perturbation {
                noise_std,
                beam_dropout: cfg.beam_dropout,
                latency_steps: cfg.latency_steps,
                actuation_noise_std: cfg.actuation_noise_std,
                dt_jitter: cfg.dt_jitter,
            };
        };
        // Drawn only for a share above 0, so runs without one keep their random streams.
        if r.clean_share > 0.0 && rng.random::<f64>() < r.clean_share {
            return Perturbation { noise_std, ..Perturbation::default() };
        }
        let mut u = |[lo, hi]: [f64; 2]| if lo < hi { rng.random_range(lo..=hi) } else { lo };
        let noise_std = u(r.noise_std);
        let beam_dropout = u(r.beam_dropout);
        let scale = u(r.actuation_noise_scale);
        let dt_jitter = u(r.dt_jitter);
        let [lo, hi] = r.latency_steps;
        let latency_steps = if lo < hi { rng.random_range(lo..=hi) } else { lo };
        Perturbation {
            noise_std,
            beam_dropout,
            latency_steps,
            actuation_noise_std: cfg.actuation_noise_std.map(|s| s * scale),
            dt_jitter,
        }
    }

    /// True when nothing is perturbed beyond LiDAR noise.
    pub fn is_clean(&self) -> bool {
        self.beam_dropout == 0.0
            && self.latency_steps == 0
            && self.actuation_noise_std == [0.0, 0.0]
            && self.dt_jitter == 0.0
    }
}

impl RobustnessConfig {
    /// What is wrong, as `(key, reason)`, with keys relative to `env.robustness`.
    pub fn check(&self) -> Result<(), (String, String)> {
        let bad = |k: &str, r: String| Err((k.to_string(), r));
        let share = |v: f64| (0.0..=1.0).contains(&v);
        let sigma = |v: f64| v.is_finite() && v >= 0.0;
        if !share(self.beam_dropout) {
            return bad(
                "beam_dropout",
                format!("must be a share in [0, 1], got {}", self.beam_dropout),
            );
        }
        if !self.actuation_noise_std.iter().all(|&s| sigma(s)) {
            return bad(
                "actuation_noise_std",
                format!("must be two σ ≥ 0 ([v m/s, ω rad/s]), got {:?}", self.actuation_noise_std),
            );
        }
        if !(0.0..1.0).contains(&self.dt_jitter) {
            return bad("dt_jitter", format!("must be in [0, 1), got {}", self.dt_jitter));
        }
        if self.latency_steps > MAX_LATENCY {
            return bad(
                "latency_steps",
                format!("at most {MAX_LATENCY} cycles, got {}", self.latency_steps),
            );
        }
        if let Some(r) = &self.randomize {
            let range = |k: &str, [lo, hi]: [f64; 2], ok: &dyn Fn(f64) -> bool| {
                if lo <= hi && ok(lo) && ok(hi) {
                    Ok(())
                } else {
                    Err((
                        format!("randomize.{k}"),
                        format!("needs [lo, hi] with lo ≤ hi in range, got [{lo}, {hi}]"),
                    ))
                }
            };
            range("noise_std", r.noise_std, &sigma)?;
            range("beam_dropout", r.beam_dropout, &share)?;
            range("actuation_noise_scale", r.actuation_noise_scale, &sigma)?;
            range("dt_jitter", r.dt_jitter, &|v| (0.0..1.0).contains(&v))?;
            if !share(r.clean_share) {
                return bad(
                    "randomize.clean_share",
                    format!("must be a share of episodes in [0, 1], got {}", r.clean_share),
                );
            }
            let [lo, hi] = r.latency_steps;
            if lo > hi || hi > MAX_LATENCY {
                return bad(
                    "randomize.latency_steps",
                    format!("needs [lo, hi] with lo ≤ hi ≤ {MAX_LATENCY}, got [{lo}, {hi}]"),
                );
            }
        }
        Ok(())
    }
}

/// Longest observation latency (cycles): 2 s at the paper's 0.2 s period.
pub const MAX_LATENCY: u32 = 10;

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn fixed_values_pass_through_and_ranges_are_drawn_within_bounds() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(1);
        let cfg = RobustnessConfig {
            beam_dropout: 0.05,
            latency_steps: 1,
            actuation_noise_std: [0.02, 0.1],
            dt_jitter: 0.1,
            randomize: None,
        };
        let p = Perturbation::draw(&cfg, 0.02, &mut rng);
        assert_eq!(
            p,
            Perturbation {
                noise_std: 0.02,
                beam_dropout: 0.05,
                latency_steps: 1,
                actuation_noise_std: [0.02, 0.1],
                dt_jitter: 0.1
            }
        );
        assert!(!p.is_clean());
        assert!(Perturbation::draw(&RobustnessConfig::default(), 0.0, &mut rng).is_clean());
        let cfg = RobustnessConfig {
            randomize: Some(RandomizeConfig {
                noise_std: [0.0, 0.03],
                beam_dropout: [0.0, 0.1],
                latency_steps: [0, 2],
                actuation_noise_scale: [0.0, 1.0],
                dt_jitter: [0.0, 0.2],
                clean_share: 0.0,
            }),
            ..cfg
        };
        let mut latencies = [0; 3];
        for _ in 0..300 {
            let p = Perturbation::draw(&cfg, 0.5, &mut rng);
            assert!((0.0..=0.03).contains(&p.noise_std));
            assert!((0.0..=0.1).contains(&p.beam_dropout));
            assert!((0.0..=0.2).contains(&p.dt_jitter));
            assert!(p.actuation_noise_std[0] <= 0.02 && p.actuation_noise_std[1] <= 0.1);
            latencies[p.latency_steps as usize] += 1;
        }
        assert!(latencies.iter().all(|&n| n > 50), "{latencies:?}");
    }

    #[test]
    fn bad_values_name_their_key() {
        let key = |c: RobustnessConfig| c.check().unwrap_err().0;
        assert_eq!(
            key(RobustnessConfig { beam_dropout: 1.5, ..Default::default() }),
            "beam_dropout"
        );
        assert_eq!(key(RobustnessConfig { dt_jitter: 1.0, ..Default::default() }), "dt_jitter");
        assert_eq!(
            key(RobustnessConfig { latency_steps: 99, ..Default::default() }),
            "latency_steps"
        );
        assert_eq!(
            key(RobustnessConfig { actuation_noise_std: [-0.1, 0.0], ..Default::default() }),
            "actuation_noise_std"
        );
        let r = RandomizeConfig { noise_std: [0.03, 0.01], ..Default::default() };
        assert_eq!(
            key(RobustnessConfig { randomize: Some(r), ..Default::default() }),
            "randomize.noise_std"
        );
        let r = RandomizeConfig { clean_share: 1.5, ..Default::default() };
        assert_eq!(
            key(RobustnessConfig { randomize: Some(r), ..Default::default() }),
            "randomize.clean_share"
        );
        assert!(RobustnessConfig::default().check().is_ok());
    }

    #[test]
    fn a_clean_share_of_episodes_runs_unperturbed_and_the_rest_draw_from_the_ranges() {
        let ranges = RandomizeConfig {
            noise_std: [0.01, 0.03],
            beam_dropout: [0.02, 0.08],
            latency_steps: [1, 1],
            actuation_noise_scale: [0.5, 1.0],
            dt_jitter: [0.05, 0.1],
            clean_share: 0.3,
        };
        let cfg = RobustnessConfig {
            actuation_noise_std: [0.02, 0.1],
            randomize: Some(ranges.clone()),
            ..Default::default()
        };
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let draws: Vec<_> = (0..2000).map(|_| Perturbation::draw(&cfg, 0.005, &mut rng)).collect();
        let clean: Vec<_> = draws.iter().filter(|p| p.is_clean()).collect();
        // Every range above starts above 0, so an unperturbed episode is a clean draw.
        assert!(clean.iter().all(|p| p.noise_std == 0.005 && p.latency_steps == 0));
        let share = clean.len() as f64 / draws.len() as f64;
        assert!((share - 0.3).abs() < 0.04, "clean share {share}");
        assert!(draws.iter().filter(|p| !p.is_clean()).all(|p| p.noise_std >= 0.01));

        // A share of 0 leaves the stream as it was: the same draws as before the key existed.
        let without = RobustnessConfig {
            randomize: Some(RandomizeConfig { clean_share: 0.0, ..ranges }),
            ..cfg
        };
        let mut a = rand_pcg::Pcg64::seed_from_u64(7);
        let mut b = rand_pcg::Pcg64::seed_from_u64(7);
        let first = Perturbation::draw(&without, 0.0, &mut a);
        let mut u = |[lo, hi]: [f64; 2]| b.random_range(lo..=hi);
        assert_eq!(first.noise_std, u([0.01, 0.03]));
        assert!(!toml::to_string(&without).unwrap().contains("clean_share"));
    }
}
