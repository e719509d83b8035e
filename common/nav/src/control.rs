//! The PID warm-up controller of the paper (Xie et al. 2021): drive towards the goal expressed in
//! the robot frame. Only the proportional terms are used, as in the design. And the planner
//! expert ([`expert_velocity`]): the same controller aimed at the planner's subgoal, turning in
//! place first when the subgoal is far off its heading.

use dvnav_config::{EnvConfig, WarmupConfig};
use dvnav_sim::NavEnv;

/// v = clip(kp_v·x_g, 0, v_max), ω = clip(kp_ω·y_g, −ω_max, ω_max), with (x_g, y_g) the goal in
/// the robot frame (x ahead, y left). Returns (v, ω) in m/s and rad/s.
pub fn pid_velocity(
    goal_distance: f64,
    goal_angle: f64,
    warmup: &WarmupConfig,
    env: &EnvConfig,
) -> (f64, f64) {
    let (x_g, y_g) = (goal_distance * goal_angle.cos(), goal_distance * goal_angle.sin());
    let v = (warmup.kp_linear * x_g).clamp(0.0, env.v_max);
    let omega = (warmup.kp_angular * y_g).clamp(-env.omega_max, env.omega_max);
    (v, omega)
}

/// The planner expert's command towards a subgoal on the planner's path at `subgoal_distance`
/// (m) and `subgoal_angle` (rad, robot frame): turn in place at ω_max while the subgoal is more
/// than `warmup.expert_turn_deg` off the heading (an arc towards a subgoal behind the robot
/// would swing its body into the wall it is going round), then [`pid_velocity`] on it.
pub fn expert_velocity(
    subgoal_distance: f64,
    subgoal_angle: f64,
    warmup: &WarmupConfig,
    env: &EnvConfig,
) -> (f64, f64) {
    if subgoal_angle.abs() > warmup.expert_turn_deg.to_radians() {
        (0.0, env.omega_max.copysign(subgoal_angle))
    } else {
        pid_velocity(subgoal_distance, subgoal_angle, warmup, env)
    }
}

/// The planner expert's command for `env`'s robot now, in the meta robot's units (as the
/// policy commands a robot of any size: the environment scales it through DVST): aimed at the
/// subgoal on the episode's planned path. `None` when the episode has no path
/// (`env.subgoals` unset, or no path found).
pub fn expert_command(env: &NavEnv, warmup: &WarmupConfig) -> Option<(f64, f64)> {
    let subgoal = env.planned_subgoal()?;
    let pose = env.pose();
    let distance = (subgoal[0] - pose.x).hypot(subgoal[1] - pose.y) / env.dvst_scale();
    Some(expert_velocity(distance, pose.bearing_to(subgoal), warmup, env.config()))
}

/// Maps physical velocities to the policy's normalized action in [-1, 1]², the inverse of
/// [`action_to_velocity`], so PID steps can be stored in the replay buffer like policy steps.
pub fn velocity_to_action(v: f64, omega: f64, env: &EnvConfig) -> [f32; 2] {
    [
        ((2.0 * v / env.v_max) - 1.0).clamp(-1.0, 1.0) as f32,
        (omega / env.omega_max).clamp(-1.0, 1.0) as f32,
    ]
}

/// v = (a0 + 1)/2 · v_max, ω = a1 · ω_max (design §3).
pub fn action_to_velocity(action: [f32; 2], env: &EnvConfig) -> (f64, f64) {
    let a0 = (action[0] as f64).clamp(-1.0, 1.0);
    let a1 = (action[1] as f64).clamp(-1.0, 1.0);
    ((a0 + 1.0) * 0.5 * env.v_max, a1 * env.omega_max)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn goal_ahead_drives_straight_at_full_speed() {
        let (v, w) = pid_velocity(3.0, 0.0, &WarmupConfig::default(), &EnvConfig::default());
        assert_eq!(v, 0.5);
        assert_eq!(w, 0.0);
    }

    #[test]
    fn goal_behind_turns_in_place_towards_it() {
        let env = EnvConfig::default();
        let (v, w) = pid_velocity(2.0, 2.5, &WarmupConfig::default(), &env);
        assert_eq!(v, 0.0);
        assert_eq!(w, env.omega_max);
        let (v, w) = pid_velocity(2.0, -2.5, &WarmupConfig::default(), &env);
        assert_eq!(v, 0.0);
        assert_eq!(w, -env.omega_max);
    }

    #[test]
    fn small_offsets_are_proportional() {
        let env = EnvConfig::default();
        // Goal 0.2 m ahead and 0.05 m to the left: v = 0.2, ω = 0.5.
        let d = (0.2f64.powi(2) + 0.05f64.powi(2)).sqrt();
        let (v, w) = pid_velocity(d, 0.05f64.atan2(0.2), &WarmupConfig::default(), &env);
        assert!((v - 0.2).abs() < 1e-12 && (w - 0.5).abs() < 1e-12, "{v} {w}");
    }

    #[test]
    fn the_expert_turns_in_place_until_the_subgoal_is_ahead() {
        let env = EnvConfig::default();
        let w = WarmupConfig::default();
        assert_eq!(expert_velocity(1.5, 1.0, &w, &env), (0.0, env.omega_max));
        assert_eq!(expert_velocity(1.5, -2.0, &w, &env), (0.0, -env.omega_max));
        // Within the angle it is the PID controller on the subgoal.
        let a = 0.3;
        assert_eq!(expert_velocity(1.5, a, &w, &env), pid_velocity(1.5, a, &w, &env));
        assert!(expert_velocity(1.5, a, &w, &env).0 > 0.0);
    }

    #[test]
    fn action_mapping_round_trips() {
        let env = EnvConfig::default();
        for &(v, w) in &[(0.0, 0.0), (0.5, 1.0), (0.25, -1.2)] {
            let a = velocity_to_action(v, w, &env);
            let (v2, w2) = action_to_velocity(a, &env);
            assert!((v - v2).abs() < 1e-6 && (w - w2).abs() < 1e-6);
        }
    }
}

/// The planner expert in rooms whose goals sit behind a wall (`generated:walls`, training
/// seeds): what it reaches, mapless (the agent would observe the final goal) and through DVST.
#[cfg(test)]
mod expert_tests {
    use super::*;
    use dvnav_sim::DvstTrainingConfig;
    use dvnav_sim::subgoal::SubgoalConfig;
    use dvnav_sim::{Outcome, Room};

    /// Success rate of the expert over `episodes` episodes in walls rooms 0..10.
    fn success_rate(cfg: &EnvConfig, episodes: usize) -> f64 {
        let warmup = WarmupConfig::default();
        let mut successes = 0;
        for k in 0..episodes {
            let room = Room::load(&format!("generated:walls:{}", k % 10)).unwrap().remove(0);
            let mut env = NavEnv::new(room, cfg, k as u64);
            let outcome = loop {
                let (v, w) = expert_command(&env, &warmup).expect("a planned path");
                if let Some(o) = env.step(v, w).done {
                    break o;
                }
            };
            successes += usize::from(outcome == Outcome::Success);
        }
        successes as f64 / episodes as f64
    }

    fn mapless() -> EnvConfig {
        let subgoals = SubgoalConfig { follow_share: 0.0, ..SubgoalConfig::default() };
        EnvConfig { subgoals: Some(subgoals), ..EnvConfig::default() }
    }

    #[test]
    fn the_expert_reaches_goals_behind_walls_while_the_agent_sees_the_final_goal() {
        let cfg = mapless();
        let room = Room::load("generated:walls:3").unwrap().remove(0);
        let env = NavEnv::new(room, &cfg, 0);
        assert!(env.subgoal().is_none(), "mapless: the agent observes the final goal");
        assert!(env.planned_subgoal().is_some());
        let rate = success_rate(&cfg, 40);
        eprintln!("expert, meta robot: {rate}");
        assert!(rate >= 0.9, "{rate}");
    }

    #[test]
    fn the_expert_drives_bigger_robots_through_dvst() {
        let dvst = DvstTrainingConfig { radius_range: [0.4, 0.6], share: 1.0 };
        let cfg = EnvConfig { dvst: Some(dvst), ..mapless() };
        let rate = success_rate(&cfg, 40);
        eprintln!("expert, R 0.4-0.6: {rate}");
        assert!(rate >= 0.8, "{rate}");
    }

    #[test]
    fn without_subgoals_there_is_no_expert() {
        let room = Room::load("generated:walls:3").unwrap().remove(0);
        let env = NavEnv::new(room, &EnvConfig::default(), 0);
        assert_eq!(expert_command(&env, &WarmupConfig::default()), None);
    }
}
