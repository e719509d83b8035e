//! The stall escape: a recovery behaviour for a reactive policy that stops making progress.
//!
//! A mapless policy driven deterministically (a = tanh μ(s)) can settle into a fixed point or
//! a cycle: a big robot (through DVST) frozen where every side looks too close, or a robot
//! circling in front of the obstacle between it and its goal. SAC trained a distribution, not
//! only its mean; sampling it breaks the symmetry that holds the deterministic policy, with
//! actions the agent itself rates well. So, as Nav2's progress checker hands a stuck robot to
//! its recovery behaviours, [`StallEscape`] watches the goal distance: after `after_s` seconds
//! without `min_progress_m` of progress it asks for the policy's own noise (ε ~ N(0, I), the
//! action tanh(μ + σ·ε)) for `after_s` seconds, then drives deterministically again, and
//! escapes again after another `after_s` seconds without progress (counted from the last
//! progress, made during the escape or not).
//!
//! One ε is drawn per escape and held through it: the policy's own action shifted by a fixed
//! latent offset, a coherent manoeuvre. A fresh ε every cycle escaped as often on tuning rooms
//! but turned ω back and forth (ω reversals of 12.1 % of cycles against 3.5 % in Env_3 at
//! R = 0.4, docs/results.md "The stall escape").
//!
//! The noise comes from the escape's own seeded generator, so an evaluation replays exactly.

use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use rand_pcg::Pcg64Mcg;

/// The progress that counts, as a share of the robot's (bounding) radius: 0.1 m for the 0.2 m
/// meta robot, and a robot through DVST must come as much closer as its size scales.
pub const PROGRESS_RADII: f64 = 0.5;

/// Progress watch and noise source of one robot.
#[derive(Clone, Debug)]
pub struct StallEscape {
    after_s: f64,
    min_progress_m: f64,
    /// The least goal distance seen, and when.
    best_m: f64,
    best_t: f64,
    /// The current escape runs until this time (−∞: none).
    until: f64,
    /// The goal distance and time of the last [`follow_goal`](Self::follow_goal) call.
    last: Option<(f64, f64)>,
    /// The current escape's ε, drawn when it began.
    eps: [f32; 2],
    rng: Pcg64Mcg,
}

impl StallEscape {
    /// An escape after `after_s` seconds (> 0) without `min_progress_m` (> 0) of progress
    /// towards the goal; its noise from a generator seeded with `seed`.
    pub fn new(after_s: f64, min_progress_m: f64, seed: u64) -> anyhow::Result<Self> {
        anyhow::ensure!(
            after_s.is_finite() && after_s > 0.0,
            "the stall escape's delay must be a time above 0 s, not {after_s}"
        );
        anyhow::ensure!(
            min_progress_m.is_finite() && min_progress_m > 0.0,
            "the stall escape's progress must be a distance above 0 m, not {min_progress_m}"
        );
        Ok(Self {
            after_s,
            min_progress_m,
            best_m: f64::INFINITY,
            best_t: 0.0,
            until: f64::NEG_INFINITY,
            last: None,
            eps: [0.0; 2],
            rng: Pcg64Mcg::seed_from_u64(seed),
        })
    }

    /// An escape for a robot of (bounding) radius `radius_m`: progress is [`PROGRESS_RADII`]
    /// of it.
    pub fn for_radius(after_s: f64, radius_m: f64, seed: u64) -> anyhow::Result<Self> {
        Self::new(after_s, PROGRESS_RADII * radius_m, seed)
    }

    /// A new goal: forget the progress seen (the generator goes on).
    pub fn reset(&mut self) {
        self.best_m = f64::INFINITY;
        self.best_t = 0.0;
        self.until = f64::NEG_INFINITY;
    }

    /// For a caller that is not told when the goal changes (a robot's controller, which sees
    /// only the goal's distance each cycle): a distance that changed by more than a robot at
    /// `v_max_mps` could drive since the last call (with half as much again, and
    /// `min_progress_m`, for slack) is a new goal, and [`reset`](Self::reset)s the watch.
    pub fn follow_goal(&mut self, t_s: f64, goal_distance_m: f64, v_max_mps: f64) {
        if let Some((t0, d0)) = self.last {
            let reach = 1.5 * v_max_mps * (t_s - t0).max(0.0) + self.min_progress_m;
            if (goal_distance_m - d0).abs() > reach {
                self.reset();
            }
        }
        self.last = Some((t_s, goal_distance_m));
    }

    /// Whether an escape runs at `t_s` (as the last [`noise`](Self::noise) call left it).
    pub fn escaping(&self, t_s: f64) -> bool {
        t_s < self.until
    }

    /// The cycle at `t_s` seconds since the goal was set, `goal_distance_m` from it: the noise
    /// ε for the policy's action while an escape runs (the same through one escape), else
    /// `None` (act deterministically).
    pub fn noise(&mut self, t_s: f64, goal_distance_m: f64) -> Option<[f32; 2]> {
        if goal_distance_m < self.best_m - self.min_progress_m || self.best_m.is_infinite() {
            self.best_m = goal_distance_m;
            self.best_t = t_s;
        }
        if t_s >= self.until && t_s - self.best_t >= self.after_s {
            // Escape for `after_s`; without progress during it, watch as long again before the
            // next one.
            self.until = t_s + self.after_s;
            self.best_t = self.until;
            self.eps = [self.rng.sample(StandardNormal), self.rng.sample(StandardNormal)];
        }
        (t_s < self.until).then_some(self.eps)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT: f64 = 0.2;

    /// The cycles (by index) at which the escape asked for noise over `n` cycles of a goal
    /// distance given per cycle.
    fn escaping_cycles(e: &mut StallEscape, n: usize, d: impl Fn(usize) -> f64) -> Vec<usize> {
        (0..n).filter(|&k| e.noise(k as f64 * DT, d(k)).is_some()).collect()
    }

    #[test]
    fn a_robot_making_progress_is_never_disturbed() {
        let mut e = StallEscape::new(3.0, 0.1, 1).unwrap();
        // 0.05 m closer every cycle: 0.1 m every 0.4 s, far inside 3 s.
        assert!(escaping_cycles(&mut e, 500, |k| 20.0 - 0.05 * k as f64).is_empty());
    }

    #[test]
    fn a_frozen_robot_escapes_for_the_delay_then_watches_as_long_again() {
        let mut e = StallEscape::new(1.0, 0.1, 1).unwrap();
        let cycles = escaping_cycles(&mut e, 30, |_| 4.0);
        // 1 s = 5 cycles: watched 0..4, escape 5..9, watched 10..14, escape 15..19, ...
        assert_eq!(cycles, vec![5, 6, 7, 8, 9, 15, 16, 17, 18, 19, 25, 26, 27, 28, 29]);
    }

    #[test]
    fn progress_during_an_escape_restarts_the_watch_and_a_new_goal_forgets_the_old_one() {
        let mut e = StallEscape::new(1.0, 0.1, 1).unwrap();
        // Stuck for 7 cycles, then 0.2 m closer at cycle 7 (1.4 s), in the escape of 5..9.
        let cycles = escaping_cycles(&mut e, 20, |k| if k < 7 { 4.0 } else { 3.8 });
        // The escape runs its second; the next comes 1 s after that progress, at 2.4 s.
        assert_eq!(cycles, vec![5, 6, 7, 8, 9, 12, 13, 14, 15, 16]);
        // A new goal far away: a fresh start, no escape for the delay.
        e.reset();
        assert_eq!(e.noise(0.0, 9.0), None);
        assert_eq!(e.noise(0.8, 9.0), None);
        assert!(e.noise(1.0, 9.0).is_some());
    }

    #[test]
    fn a_goal_that_jumps_further_than_the_robot_drives_is_a_new_goal() {
        let mut e = StallEscape::new(1.0, 0.1, 1).unwrap();
        let mut step = |k: usize, d: f64| {
            e.follow_goal(k as f64 * DT, d, 0.5);
            e.noise(k as f64 * DT, d).is_some()
        };
        // Stuck at 4 m: the escape begins at cycle 5.
        assert!(!(0..5).any(|k| step(k, 4.0)));
        assert!(step(5, 4.0));
        // 0.12 m further in one 0.2 s cycle is within reach (0.5 m/s · 1.5 · 0.2 s + 0.1 m):
        // the same goal, the escape goes on.
        assert!(step(6, 4.12));
        // A new goal 3 m away: the watch starts over, no escape for the next second.
        assert!(!(7..12).any(|k| step(k, 7.0)));
        assert!(step(12, 7.0));
    }

    #[test]
    fn one_draw_is_held_through_an_escape_and_the_next_draws_anew() {
        let mut e = StallEscape::new(1.0, 0.1, 4).unwrap();
        let eps: Vec<_> = (0..30).filter_map(|k| e.noise(k as f64 * DT, 4.0)).collect();
        // Escapes at cycles 5..9, 15..19, 25..29: 5 cycles each.
        assert_eq!(eps.len(), 15);
        for w in eps.chunks(5) {
            assert!(w.iter().all(|x| *x == w[0]), "{w:?}");
        }
        assert!(eps[0] != eps[5] && eps[5] != eps[10]);
    }

    #[test]
    fn noise_is_standard_normal_and_replays_from_its_seed() {
        let draw = |seed| {
            let mut e = StallEscape::new(0.2, 0.1, seed).unwrap();
            (0..20_000).filter_map(|k| e.noise(k as f64 * DT, 1.0)).flatten().collect::<Vec<_>>()
        };
        let x = draw(7);
        assert_eq!(x, draw(7));
        assert_ne!(x, draw(8));
        let n = x.len() as f64;
        let mean = x.iter().map(|&v| v as f64).sum::<f64>() / n;
        let var = x.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / n;
        assert!(n > 15_000.0, "{n} draws");
        assert!(mean.abs() < 0.03 && (var - 1.0).abs() < 0.05, "mean {mean}, variance {var}");
    }

    #[test]
    fn bad_settings_are_refused_naming_the_value() {
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let e = StallEscape::new(bad, 0.1, 0).unwrap_err().to_string();
            assert!(e.contains("delay") && e.contains(&bad.to_string()), "{e}");
            let e = StallEscape::new(1.0, bad, 0).unwrap_err().to_string();
            assert!(e.contains("progress"), "{e}");
        }
    }
}
