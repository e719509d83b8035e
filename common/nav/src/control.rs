//! The PID warm-up controller of the paper (Xie et al. 2021): drive towards the goal expressed in
//! the robot frame. Only the proportional terms are used, as in the design.

use dvnav_config::{EnvConfig, WarmupConfig};

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
    fn action_mapping_round_trips() {
        let env = EnvConfig::default();
        for &(v, w) in &[(0.0, 0.0), (0.5, 1.0), (0.25, -1.2)] {
            let a = velocity_to_action(v, w, &env);
            let (v2, w2) = action_to_velocity(a, &env);
            assert!((v - v2).abs() < 1e-6 && (w - w2).abs() < 1e-6);
        }
    }
}
