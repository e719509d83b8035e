//! [`Dvst`]: any [`NavPolicy`] for the meta robot, driving a dimension-varied robot.

use super::footprint_file::VariedRobot;
use super::scale::MetaRobot;
use super::transfer::{VelocityBounds, transfer_observation, transfer_policy};
use crate::policy::NavPolicy;
use dvnav_sim::obs::obs_dim;
use dvnav_sim::{EnvConfig, Footprint};

/// The meta policy `P` wrapped by DVST: a [`NavPolicy`] for the varied robot. Each
/// [`act`](NavPolicy::act) transfers the varied robot's observation to the meta robot
/// ([`transfer_observation`], clamped to the meta LiDAR's range when
/// [`with_scan_range`](Dvst::with_scan_range) gave it), asks `P`, and transfers the command
/// back ([`transfer_policy`]) within the varied robot's own bounds.
#[derive(Debug)]
pub struct Dvst<P> {
    meta: P,
    robot: VariedRobot,
    mu: f64,
    bounds: VelocityBounds,
    /// The meta agent's LiDAR range `[min, max]` (m), if known.
    scan_range: Option<[f64; 2]>,
    /// The transferred observation, reused across calls.
    scratch: Vec<f32>,
}

impl<P: NavPolicy> Dvst<P> {
    /// Wraps `meta` for `robot`; the robot's missing velocity bounds are the meta policy's.
    pub fn new(meta: P, robot: VariedRobot) -> anyhow::Result<Self> {
        check_standard_observation(&meta)?;
        robot.validate()?;
        let (v_max, omega_max) = meta.velocity_bounds();
        let bounds = robot.velocity_bounds(VelocityBounds { v_max, omega_max });
        bounds.validate()?;
        let scratch = vec![0.0; obs_dim(meta.beams())];
        Ok(Self { mu: robot.mu(), meta, robot, bounds, scan_range: None, scratch })
    }

    /// `meta`, the agent of a run whose env config is `env`, for `robot`: the robot's meta
    /// robot must be the one that run trained ([`MetaRobot::trained`]), and transferred scans
    /// keep within that run's LiDAR range ([`with_scan_range`](Dvst::with_scan_range)).
    pub fn for_run(meta: P, env: &EnvConfig, robot: VariedRobot) -> anyhow::Result<Self> {
        let trained = MetaRobot::trained(env)?;
        anyhow::ensure!(
            robot.meta == trained,
            "the footprint file's meta robot differs from the one the model was trained as: the \
             file's is {:?}, the model's {trained:?}",
            robot.meta
        );
        Self::new(meta, robot)?.with_scan_range(Some([env.lidar.range_min, env.lidar.range_max]))
    }

    /// Keeps transferred scans within `[min, max]` (m), the range of the LiDAR the meta policy
    /// was trained with (`env.lidar.range_min`, `range_max` of its run config); see
    /// [`transfer_observation`] for why. `None`: the paper's plain division.
    pub fn with_scan_range(mut self, range: Option<[f64; 2]>) -> anyhow::Result<Self> {
        if let Some([lo, hi]) = range {
            anyhow::ensure!(
                lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo < hi,
                "scan range must be 0 ≤ min < max, got [{lo}, {hi}]"
            );
        }
        self.scan_range = range;
        Ok(self)
    }

    /// The scale factor μ of the current footprint.
    pub fn mu(&self) -> f64 {
        self.mu
    }

    /// The dimension-scaled robot the meta policy is driving.
    pub fn scaled_robot(&self) -> MetaRobot {
        self.robot.meta.scaled(self.mu)
    }

    /// The varied robot as configured now.
    pub fn robot(&self) -> &VariedRobot {
        &self.robot
    }

    /// The wrapped meta policy.
    pub fn meta_policy(&self) -> &P {
        &self.meta
    }

    /// A new footprint at run time (the robot picked up or set down cargo): recomputes μ and
    /// returns it. Meta robot, margin and bounds stay. An invalid footprint changes nothing.
    pub fn set_footprint(&mut self, footprint: Footprint) -> anyhow::Result<f64> {
        footprint.validate()?;
        self.robot.footprint = footprint;
        self.mu = self.robot.mu();
        Ok(self.mu)
    }

    /// A new varied robot at run time, whole: footprint, meta robot, margin and bounds, as if
    /// DVST had been built for `robot` (the robot's missing bounds are the meta policy's).
    /// Recomputes μ and returns it. An invalid robot changes nothing.
    pub fn set_robot(&mut self, robot: VariedRobot) -> anyhow::Result<f64> {
        robot.validate()?;
        let (v_max, omega_max) = self.meta.velocity_bounds();
        let bounds = robot.velocity_bounds(VelocityBounds { v_max, omega_max });
        bounds.validate()?;
        self.mu = robot.mu();
        self.robot = robot;
        self.bounds = bounds;
        Ok(self.mu)
    }
}

/// DVST transfers the standard observation (scan, goal, velocity): a policy taking more
/// cannot be wrapped.
pub(crate) fn check_standard_observation(meta: &impl NavPolicy) -> anyhow::Result<()> {
    anyhow::ensure!(
        meta.obs_dim() == obs_dim(meta.beams()),
        "DVST transfers the standard observation of {} values; this policy takes {} (a policy \
         with the robot radius as an input is driven with each robot's own radius)",
        obs_dim(meta.beams()),
        meta.obs_dim()
    );
    Ok(())
}

impl<P: NavPolicy> NavPolicy for Dvst<P> {
    fn beams(&self) -> usize {
        self.meta.beams()
    }

    fn act(&mut self, obs: &[f32]) -> anyhow::Result<(f64, f64)> {
        let d = obs_dim(self.meta.beams());
        anyhow::ensure!(obs.len() == d, "observation has {} values, expected {d}", obs.len());
        self.act_row(obs, None)
    }

    fn velocity_bounds(&self) -> (f64, f64) {
        (self.bounds.v_max, self.bounds.omega_max)
    }

    /// The meta policy's noisy action (the stall escape), transferred as any other.
    fn act_batch_noisy(
        &mut self,
        obs: &[f32],
        noise: &[Option<[f32; 2]>],
    ) -> anyhow::Result<Vec<(f64, f64)>> {
        let beams = self.meta.beams();
        let d = obs_dim(beams);
        anyhow::ensure!(
            obs.len() == noise.len() * d,
            "{} observation values for {} noise rows: expected {d} per row",
            obs.len(),
            noise.len()
        );
        obs.chunks_exact(d).zip(noise).map(|(o, &n)| self.act_row(o, n)).collect()
    }
}

impl<P: NavPolicy> Dvst<P> {
    /// One observation of the right length through the meta policy: its deterministic action,
    /// or the one sampled with noise `n`, transferred back to the robot.
    fn act_row(&mut self, obs: &[f32], n: Option<[f32; 2]>) -> anyhow::Result<(f64, f64)> {
        let beams = self.meta.beams();
        transfer_observation(obs, beams, self.mu, self.scan_range, &mut self.scratch);
        let (v_m, omega_m) = match n {
            None => self.meta.act(&self.scratch)?,
            Some(_) => self.meta.act_batch_noisy(&self.scratch, &[n])?[0],
        };
        anyhow::ensure!(
            v_m.is_finite() && omega_m.is_finite(),
            "the meta policy answered a non-finite command ({v_m}, {omega_m})"
        );
        Ok(transfer_policy(v_m, omega_m, self.mu, self.bounds))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dvnav_sim::ObstacleSpec;
    use dvnav_sim::obs::{ANGULAR_VELOCITY, GOAL_ANGLE, GOAL_DISTANCE, LINEAR_VELOCITY};

    /// A meta policy that records what it saw and answers a fixed command.
    #[derive(Debug)]
    struct Recorder {
        seen: Vec<Vec<f32>>,
        command: (f64, f64),
    }

    impl NavPolicy for Recorder {
        fn beams(&self) -> usize {
            3
        }
        fn act(&mut self, obs: &[f32]) -> anyhow::Result<(f64, f64)> {
            self.seen.push(obs.to_vec());
            Ok(self.command)
        }
        fn velocity_bounds(&self) -> (f64, f64) {
            (0.5, 1.5)
        }
    }

    /// A meta policy that answers (0.1, 0) deterministically and (0.2, ε₀) for noise ε.
    #[derive(Debug)]
    struct NoisyProbe {
        seen: Vec<Vec<f32>>,
    }

    impl NavPolicy for NoisyProbe {
        fn beams(&self) -> usize {
            3
        }
        fn act(&mut self, _obs: &[f32]) -> anyhow::Result<(f64, f64)> {
            Ok((0.1, 0.0))
        }
        fn velocity_bounds(&self) -> (f64, f64) {
            (0.5, 1.5)
        }
        fn act_batch_noisy(
            &mut self,
            obs: &[f32],
            noise: &[Option<[f32; 2]>],
        ) -> anyhow::Result<Vec<(f64, f64)>> {
            self.seen.push(obs.to_vec());
            Ok(noise.iter().map(|n| n.map_or((0.1, 0.0), |e| (0.2, e[0] as f64))).collect())
        }
    }

    #[test]
    fn the_meta_policy_samples_for_the_noisy_rows_on_the_transferred_observation() {
        let mut dvst =
            Dvst::new(NoisyProbe { seen: Vec::new() }, VariedRobot::new(Footprint::circle(0.4)))
                .unwrap();
        let obs = [1.0, 2.0, 10.0, 4.0, 0.3, 0.2, -0.5];
        let two: Vec<f32> = obs.iter().chain(&obs).copied().collect();
        let out = dvst.act_batch_noisy(&two, &[None, Some([0.25, 0.0])]).unwrap();
        // μ = 2: v doubles, ω stays (within the meta agent's bounds).
        assert_eq!(out, vec![(0.2, 0.0), (0.4, 0.25)]);
        let seen = &dvst.meta_policy().seen;
        assert_eq!(seen.len(), 1, "only the noisy row asked for the meta policy's noise");
        assert_eq!(seen[0][..3], [0.5, 1.0, 5.0], "the scan in the meta robot's frame");
        assert!(dvst.act_batch_noisy(&two, &[None]).is_err(), "one noise entry per row");
    }

    #[test]
    fn for_a_run_the_robot_s_meta_robot_is_the_trained_one_and_scans_keep_its_range() {
        let rec = || Recorder { seen: Vec::new(), command: (0.1, 0.1) };
        let env = EnvConfig::default();
        let robot = VariedRobot::new(Footprint::circle(0.4));
        let dvst = Dvst::for_run(rec(), &env, robot.clone()).unwrap();
        assert_eq!(dvst.scan_range, Some([env.lidar.range_min, env.lidar.range_max]));
        assert_eq!(dvst.mu(), 2.0);
        let other = EnvConfig { robot_radius: 0.3, ..EnvConfig::default() };
        let e = Dvst::for_run(rec(), &other, robot).unwrap_err().to_string();
        assert!(e.contains("meta robot differs from the one the model was trained as"), "{e}");
    }

    #[test]
    fn wraps_a_policy_and_follows_a_change_of_footprint() {
        let meta = Recorder { seen: Vec::new(), command: (0.4, 1.0) };
        let mut robot = VariedRobot::new(Footprint::circle(0.2));
        robot.v_max = Some(0.6);
        let mut dvst = Dvst::new(meta, robot).unwrap();
        assert_eq!(dvst.mu(), 1.0);
        assert!(dvst.scan_range.is_none());
        assert_eq!(dvst.velocity_bounds(), (0.6, 1.5), "own v_max, the meta agent's omega_max");
        let obs = [1.0, 2.0, 10.0, 4.0, 0.3, 0.2, -0.5];
        assert_eq!(dvst.act(&obs).unwrap(), (0.4, 1.0), "identity at mu = 1");
        assert_eq!(dvst.meta_policy().seen[0], obs);

        // It picks up a disc of cargo: now it reaches 0.5 m from the axle, μ = 2.5.
        let cargo = ObstacleSpec::Circle { center: [-0.35, 0.0], radius: 0.15 };
        let mu = dvst.set_footprint(Footprint::circle(0.2).with_cargo([cargo])).unwrap();
        assert!((mu - 2.5).abs() < 1e-12 && dvst.mu() == mu);
        assert_eq!(dvst.scaled_robot(), MetaRobot::Circle { radius: 0.2 * mu });
        let (v, w) = dvst.act(&obs).unwrap();
        // v_ideal = 1.0 > v_max = 0.6 and ρ = 1 ≥ v_max/ω_max: v = 0.6, ω = 0.6.
        assert!((v - 0.6).abs() < 1e-12 && (w - 0.6).abs() < 1e-12, "({v}, {w})");
        let seen = &dvst.meta_policy().seen[1];
        assert_eq!(seen[..3], [0.4, 0.8, 4.0], "scan / mu");
        assert_eq!(seen[3 + GOAL_DISTANCE], 4.0 / 2.5);
        assert_eq!(seen[3 + GOAL_ANGLE], 0.3);
        assert_eq!(seen[3 + LINEAR_VELOCITY], 0.2 / 2.5);
        assert_eq!(seen[3 + ANGULAR_VELOCITY], -0.5);

        // An invalid footprint is refused and changes nothing.
        let bad = Footprint { name: String::new(), parts: vec![] };
        assert!(dvst.set_footprint(bad.clone()).is_err());
        assert!((dvst.mu() - 2.5).abs() < 1e-12);
        assert!(dvst.act(&obs[..6]).is_err(), "wrong observation length");

        // A whole new robot: its own margin and bounds replace the old ones; a bound it leaves
        // out is the meta policy's again (v_max was 0.6).
        let mut robot = VariedRobot::new(Footprint::circle(0.3));
        (robot.margin, robot.omega_max) = (0.02, Some(0.5));
        let mu = dvst.set_robot(robot.clone()).unwrap();
        assert!((mu - 1.6).abs() < 1e-12 && dvst.mu() == mu, "{mu}");
        assert_eq!(dvst.robot(), &robot);
        assert_eq!(dvst.velocity_bounds(), (0.5, 0.5));
        let invalid = VariedRobot { margin: -1.0, ..robot.clone() };
        assert!(dvst.set_robot(invalid).is_err());
        assert!(dvst.set_robot(VariedRobot::new(bad)).is_err());
        assert_eq!((dvst.robot(), dvst.velocity_bounds()), (&robot, (0.5, 0.5)), "unchanged");
    }

    #[test]
    fn a_smaller_robot_clamps_no_return_beams_to_the_meta_range() {
        let meta = Recorder { seen: Vec::new(), command: (0.5, 0.0) };
        let dvst = Dvst::new(meta, VariedRobot::new(Footprint::circle(0.1))).unwrap();
        assert!(dvst.scan_range.is_none());
        let mut dvst = dvst.with_scan_range(Some([0.02, 10.0])).unwrap();
        assert!((dvst.mu() - 0.5).abs() < 1e-12);
        let (v, w) = dvst.act(&[10.0, 1.0, 0.005, 2.0, 0.0, 0.1, 0.0]).unwrap();
        assert_eq!((v, w), (0.25, 0.0), "straight ahead at half the meta speed");
        assert_eq!(dvst.meta_policy().seen[0][..3], [10.0, 2.0, 0.02]);
    }

    #[test]
    fn non_finite_meta_commands_are_errors() {
        let meta = Recorder { seen: Vec::new(), command: (f64::NAN, 0.0) };
        let mut dvst = Dvst::new(meta, VariedRobot::new(Footprint::circle(0.3))).unwrap();
        assert!(dvst.act(&[1.0; 7]).is_err());
        let again = Dvst::new(Recorder { seen: Vec::new(), command: (0.1, 0.1) }, dvst.robot);
        assert!(again.unwrap().with_scan_range(Some([1.0, 0.5])).is_err(), "min above max");
    }
}
