//! Tests of `env.rs`.

use super::*;
use crate::{Footprint, ObstacleSpec, RoomSpec};
use std::f64::consts::{FRAC_PI_2, PI};

fn empty_room(side: f64) -> Arc<Room> {
    Arc::new(Room::new(RoomSpec::empty("empty", side)))
}

fn cfg() -> EnvConfig {
    EnvConfig::default()
}

#[test]
fn arc_and_straight_kinematics_are_exact() {
    let p = advance(Pose2::default(), 0.5, FRAC_PI_2, 0.2);
    let r = 0.5 / FRAC_PI_2;
    let th = FRAC_PI_2 * 0.2;
    assert!((p.x - r * th.sin()).abs() < 1e-12);
    assert!((p.y - r * (1.0 - th.cos())).abs() < 1e-12);
    assert!((p.yaw - th).abs() < 1e-12);
    let q = advance(Pose2::new(1.0, 2.0, 0.3), 0.5, 0.0, 0.2);
    assert!((q.x - (1.0 + 0.1 * 0.3f64.cos())).abs() < 1e-12);
    assert!((q.y - (2.0 + 0.1 * 0.3f64.sin())).abs() < 1e-12);
    // Tiny ω is continuous with the straight line.
    let e = advance(Pose2::new(1.0, 2.0, 0.3), 0.5, 1e-9, 0.2);
    assert!((e.x - q.x).abs() < 1e-10 && (e.y - q.y).abs() < 1e-10);
    // A full circle returns home.
    let f = advance(Pose2::default(), 0.5, FRAC_PI_2, 4.0);
    assert!(f.x.abs() < 1e-12 && f.y.abs() < 1e-12);
}

#[test]
fn free_step_rewards_progress() {
    let cfg = cfg();
    let mut env = NavEnv::new(empty_room(8.0), &cfg, 1);
    env.reset_to(Pose2::new(-2.0, 0.0, 0.0), [2.0, 0.0]);
    let out = env.step(0.5, 0.0);
    // 0.1 m straight at the goal: 2·0.1 − 0.01.
    assert!((out.reward - 0.19).abs() < 1e-6, "{}", out.reward);
    assert_eq!(out.done, None);
    // A turning, clamped step: the reward is c1·(d_t − d_{t+1}) − c2 with the real poses.
    let d0 = env.goal_distance();
    let out = env.step(3.0, -5.0);
    assert_eq!(env.velocity(), (0.5, -FRAC_PI_2));
    let d1 = dist(env.pose().position(), env.goal());
    let expect = 2.0 * (d0 - d1) - 0.01;
    assert!((out.reward as f64 - expect).abs() < 1e-6, "{} vs {expect}", out.reward);
    assert!((env.pose().yaw + FRAC_PI_2 * 0.2).abs() < 1e-12);
    assert_eq!(env.steps(), 2);
    assert!((env.sim_time() - 0.4).abs() < 1e-12);
    assert!((env.episode_return() - (0.19f32 as f64 + out.reward as f64)).abs() < 1e-9);
    // Reversing is not possible: v clamps to 0, and the robot only turns.
    let before = env.pose();
    let out = env.step(-1.0, 0.0);
    assert_eq!(env.pose().position(), before.position());
    assert!((out.reward + 0.01).abs() < 1e-7);
}

#[test]
fn success_pays_r_s_and_the_env_stays_done() {
    let cfg = cfg();
    let mut env = NavEnv::new(empty_room(8.0), &cfg, 1);
    env.reset_to(Pose2::new(0.0, 0.0, 0.0), [0.29, 0.0]);
    let out = env.step(0.5, 0.0);
    assert_eq!(out, StepOutcome { reward: 10.0, done: Some(Outcome::Success) });
    let pose = env.pose();
    let again = env.step(0.5, 1.0);
    assert_eq!(again, StepOutcome { reward: 0.0, done: Some(Outcome::Success) });
    assert_eq!(env.pose(), pose);
    assert_eq!(env.steps(), 1);
    env.reset();
    assert_eq!((env.done(), env.steps(), env.velocity()), (None, 0, (0.0, 0.0)));
}

#[test]
fn collision_pays_r_c_and_stops_at_contact() {
    let cfg = cfg();
    let mut env = NavEnv::new(empty_room(4.0), &cfg, 1);
    // 0.05 m between the disc and the wall at x = 2.
    env.reset_to(Pose2::new(1.75, 0.0, 0.0), [-1.0, 0.0]);
    let out = env.step(0.5, 0.0);
    assert_eq!(out, StepOutcome { reward: -10.0, done: Some(Outcome::Collision) });
    let x = env.pose().x;
    assert!(x > 1.8 - 1e-9 && x <= 1.8 + 0.02 + 1e-9, "stopped at the first contact: {x}");
    assert_eq!(env.step(0.0, 0.0).done, Some(Outcome::Collision));
}

#[test]
fn timeout_after_max_steps() {
    let cfg = EnvConfig { max_steps: 5, ..cfg() };
    let mut env = NavEnv::new(empty_room(8.0), &cfg, 1);
    env.reset_to(Pose2::new(0.0, 0.0, 0.0), [2.0, 0.0]);
    for i in 1..=5 {
        let out = env.step(0.0, 0.5);
        assert!((out.reward + 0.01).abs() < 1e-7, "ordinary reward at step {i}");
        assert_eq!(out.done, (i == 5).then_some(Outcome::Timeout), "step {i}");
    }
    assert_eq!(env.done(), Some(Outcome::Timeout));
}

#[test]
fn no_tunneling_through_a_thin_wall() {
    // A 2 cm wall 1 m ahead, the goal behind it; 5 m per control step without sub-steps
    // would jump clean over it.
    let mut spec = RoomSpec::empty("thin", 12.0);
    spec.obstacles.push(ObstacleSpec::Box {
        center: [1.0, 0.0],
        half_extents: [0.01, 3.0],
        angle: 0.0,
    });
    let room = Arc::new(Room::new(spec));
    for (v_max, dt) in [(0.5, 1.0), (5.0, 1.0)] {
        let cfg = EnvConfig { v_max, dt, ..cfg() };
        let mut env = NavEnv::new(room.clone(), &cfg, 1);
        env.reset_to(Pose2::new(0.0, 0.0, 0.0), [3.0, 0.0]);
        let mut done = None;
        for _ in 0..10 {
            done = env.step(v_max, 0.0).done;
            assert!(env.pose().x < 1.0, "centre stays in front of the wall");
            if done.is_some() {
                break;
            }
        }
        assert_eq!(done, Some(Outcome::Collision), "v_max {v_max}");
        assert!(env.pose().x >= 0.79 - 0.02, "{}", env.pose().x);
    }
}

#[test]
fn observation_layout_and_goal_angle() {
    let cfg = cfg();
    let mut env = NavEnv::new(empty_room(8.0), &cfg, 1);
    env.reset_to(Pose2::new(1.0, 1.0, FRAC_PI_2), [0.0, 1.0]);
    let mut o = vec![0.0; env.obs_dim()];
    env.write_obs(&mut o);
    let b = 540;
    assert_eq!(o.len(), 544);
    assert_eq!(&o[..b], env.scan());
    assert!((o[b + obs::GOAL_DISTANCE] - 1.0).abs() < 1e-6);
    assert!((o[b + obs::GOAL_ANGLE] - FRAC_PI_2 as f32).abs() < 1e-6, "goal to the left");
    assert_eq!((o[b + obs::LINEAR_VELOCITY], o[b + obs::ANGULAR_VELOCITY]), (0.0, 0.0));
    // Straight behind: +π, never −π.
    env.reset_to(Pose2::new(1.0, 0.0, 0.0), [0.0, 0.0]);
    assert_eq!(env.goal_angle(), PI);
    env.reset_to(Pose2::new(0.0, 0.0, PI), [-1.0, -1.0]);
    assert!((env.goal_angle() - PI / 4.0).abs() < 1e-12, "{}", env.goal_angle());
    env.step(0.3, -0.2);
    env.write_obs(&mut o);
    assert_eq!((o[b + obs::LINEAR_VELOCITY], o[b + obs::ANGULAR_VELOCITY]), (0.3, -0.2));
    // Straight ahead, the scan reads the wall at x = −4 seen from the robot.
    let (x, yaw) = (env.pose().x, env.pose().yaw);
    let theta = env.lidar().beam_angles()[270] + yaw;
    let expect = (-4.0 - x) / theta.cos();
    assert!((o[270] as f64 - expect).abs() < 1e-3, "{} vs {expect}", o[270]);
}

#[test]
fn the_radius_input_adds_the_episodes_radius_after_omega() {
    let standard = NavEnv::new(empty_room(8.0), &cfg(), 1);
    assert_eq!(standard.obs_dim(), 544, "the meta agent's layout is unchanged");
    let cfg = EnvConfig { radius_input: true, robot_radius: 0.3, ..cfg() };
    let mut env = NavEnv::new(empty_room(8.0), &cfg, 1);
    assert_eq!(env.obs_dim(), 545);
    let mut o = vec![0.0; 545];
    env.write_obs(&mut o);
    assert_eq!(o[540 + obs::RADIUS], 0.3);
    // The standard part is what an environment without the radius input writes.
    let plain_cfg = EnvConfig { radius_input: false, ..cfg.clone() };
    let mut plain = NavEnv::new(empty_room(8.0), &plain_cfg, 1);
    let mut p = vec![0.0; 544];
    for _ in 0..5 {
        env.step(0.4, 0.3);
        plain.step(0.4, 0.3);
        env.write_obs(&mut o);
        plain.write_obs(&mut p);
        assert_eq!(o[..544], p[..]);
        assert_eq!(o[544], 0.3);
    }
    // A given footprint's radius input is its bounding radius.
    let fp = Footprint::rectangle(0.6, 0.8);
    let env = NavEnv::with_footprint(empty_room(8.0), &cfg, 1, fp);
    env.write_obs(&mut o);
    assert!((o[544] as f64 - 0.5).abs() < 1e-6, "{}", o[544]);
}

#[test]
fn radii_are_drawn_per_episode_within_the_range_and_replay_for_a_seed() {
    let cfg = EnvConfig { radius_input: true, radius_range: Some([0.2, 0.5]), ..cfg() };
    let room = Room::builtin("sac_ri").unwrap();
    let radii = |seed: u64| -> Vec<f64> {
        let mut env = NavEnv::new(room.clone(), &cfg, seed);
        let mut o = vec![0.0; env.obs_dim()];
        (0..200)
            .map(|_| {
                env.reset();
                let r = env.robot_radius();
                env.write_obs(&mut o);
                assert_eq!(o[540 + obs::RADIUS], r as f32, "the observation holds it");
                assert_eq!(env.footprint().as_circle(), Some(r), "the robot is that circle");
                // Spawn clearance follows the drawn radius.
                let need = r + cfg.spawn_clearance;
                assert!(!room.circle_collides_any_time(env.start().position(), need));
                assert!(!room.circle_collides_any_time(env.goal(), need));
                r
            })
            .collect()
    };
    let a = radii(4);
    assert!(a.iter().all(|r| (0.2..=0.5).contains(r)), "{a:?}");
    let (lo, hi) = a.iter().fold((1.0f64, 0.0f64), |(l, h), &r| (l.min(r), h.max(r)));
    assert!(lo < 0.25 && hi > 0.45, "spread over the range: {lo} .. {hi}");
    assert_eq!(a, radii(4), "the same seed draws the same radii");
    assert_ne!(a, radii(5));
    // The robot collides as the drawn circle: driving into a wall, it stops r from it.
    let mut env = NavEnv::new(empty_room(8.0), &cfg, 9);
    let r = env.robot_radius();
    env.reset_to(Pose2::new(3.0, 0.0, 0.0), [-3.0, 0.0]);
    assert_eq!(env.robot_radius(), 0.2, "a route drives robot_radius");
    env.reset();
    assert_ne!(env.robot_radius(), r, "the next random episode draws again");
    let r = env.robot_radius();
    env.begin(Pose2::new(0.0, 0.0, 0.0), [-3.0, 0.0]); // as reset left the robot
    while env.done().is_none() {
        env.step(0.5, 0.0);
    }
    assert_eq!(env.done(), Some(Outcome::Collision));
    assert!((env.pose().x - (4.0 - r)).abs() < 0.03, "{} vs r = {r}", env.pose().x);
    // A given footprint is that robot in every episode; a one-value range draws nothing.
    let mut fixed = NavEnv::with_footprint(room.clone(), &cfg, 4, Footprint::circle(0.35));
    let one = EnvConfig { radius_range: Some([0.3, 0.3]), ..cfg.clone() };
    let mut single = NavEnv::new(room.clone(), &one, 4);
    let fixed_cfg = EnvConfig { radius_range: None, robot_radius: 0.3, ..one.clone() };
    let mut none = NavEnv::new(room.clone(), &fixed_cfg, 4);
    for _ in 0..20 {
        fixed.reset();
        single.reset();
        none.reset();
        assert_eq!(fixed.robot_radius(), 0.35);
        assert_eq!(single.robot_radius(), 0.3);
        assert_eq!((single.start(), single.goal()), (none.start(), none.goal()));
    }
}

fn run_episode(env: &mut NavEnv, actions: &mut Pcg64) -> (Vec<u32>, Vec<u32>) {
    let mut obs_bits = Vec::new();
    let mut reward_bits = Vec::new();
    let mut o = vec![0.0f32; env.obs_dim()];
    env.write_obs(&mut o);
    obs_bits.extend(o.iter().map(|x| x.to_bits()));
    loop {
        let (v, w) = (actions.random_range(0.0..0.5), actions.random_range(-1.5..1.5));
        let out = env.step(v, w);
        env.write_obs(&mut o);
        obs_bits.extend(o.iter().map(|x| x.to_bits()));
        reward_bits.push(out.reward.to_bits());
        if out.done.is_some() {
            return (obs_bits, reward_bits);
        }
    }
}

#[test]
fn same_seed_same_episodes_different_seed_different() {
    let room = Room::builtin("env3").unwrap();
    let cfg = EnvConfig { max_steps: 60, ..cfg() };
    let mut a = NavEnv::new(room.clone(), &cfg, 42);
    let mut b = NavEnv::new(room.clone(), &cfg, 42);
    for episode in 0..3 {
        let ea = run_episode(&mut a, &mut Pcg64::seed_from_u64(episode));
        let eb = run_episode(&mut b, &mut Pcg64::seed_from_u64(episode));
        assert_eq!(ea, eb, "episode {episode}");
        a.reset();
        b.reset();
    }
    let c = NavEnv::new(room, &cfg, 43);
    assert_ne!((a.start(), a.goal()), (c.start(), c.goal()));
}

#[test]
fn lidar_noise_is_seeded_and_leaves_the_episodes_alone() {
    let room = Room::builtin("env1").unwrap();
    let noisy_cfg =
        EnvConfig { lidar: crate::LidarConfig { noise_std: 0.01, ..Default::default() }, ..cfg() };
    let exact = NavEnv::new(room.clone(), &cfg(), 11);
    let mut a = NavEnv::new(room.clone(), &noisy_cfg, 11);
    let mut b = NavEnv::new(room, &noisy_cfg, 11);
    assert_eq!((a.start(), a.goal()), (exact.start(), exact.goal()), "same episodes");
    assert_ne!(a.scan(), exact.scan(), "noisy");
    assert_eq!(a.scan(), b.scan(), "deterministic");
    a.step(0.2, 0.1);
    b.step(0.2, 0.1);
    assert_eq!(a.scan(), b.scan());
}

#[test]
fn set_room_takes_effect_at_reset() {
    let mut env = NavEnv::new(Room::builtin("env0").unwrap(), &cfg(), 5);
    env.set_room(Room::builtin("env3").unwrap());
    assert_eq!(env.room().name(), "env0");
    env.reset();
    assert_eq!(env.room().name(), "env3");
}

#[test]
fn builtin_rooms_sample_valid_starts_and_goals() {
    let cfg = cfg();
    let need = cfg.robot_radius + cfg.spawn_clearance;
    for name in Room::builtin_names() {
        let room = Room::builtin(&name).unwrap();
        if Room::training_names().contains(&name.as_str()) {
            assert!(!room.circle_collides([0.0, 0.0], cfg.robot_radius), "{name}: origin");
            assert!(room.clearance([0.0, 0.0], 1.0) >= 0.4 + cfg.robot_radius);
        }
        let half = room.side() / 2.0;
        let mut env = NavEnv::new(room.clone(), &cfg, 9);
        for _ in 0..200 {
            env.reset();
            let (s, g) = (env.start().position(), env.goal());
            for p in [s, g] {
                assert!(p[0].abs() < half && p[1].abs() < half, "{name}: {p:?} inside");
                assert!(room.clearance(p, 1.0) >= need - 1e-5, "{name}: {p:?} free");
            }
            assert!(dist(s, g) >= cfg.min_start_goal_distance);
            assert!(env.start().yaw > -PI && env.start().yaw <= PI);
            assert_eq!(env.pose(), env.start());
            assert!(env.scan().iter().all(|&r| r as f64 >= cfg.robot_radius));
        }
    }
}

/// A 2 cm wall across the room 1 m ahead at full speed (and at 10x the speed with a 1 s
/// control period): the circle and the rectangle footprints both stop in front of it.
#[test]
fn no_tunneling_at_full_speed_for_circle_and_rectangle() {
    let mut spec = RoomSpec::empty("thin", 12.0);
    spec.obstacles.push(ObstacleSpec::Box {
        center: [1.0, 0.0],
        half_extents: [0.01, 5.0],
        angle: 0.0,
    });
    let room = Arc::new(Room::new(spec));
    let rect = Footprint::rectangle(0.5, 0.3);
    for fp in [
        Footprint::circle(0.2),
        rect.clone(),
        rect.with_cargo([ObstacleSpec::Circle { center: [-0.4, 0.0], radius: 0.1 }]),
    ] {
        let front = fp.parts.iter().map(|p| p.aabb()[1][0]).fold(f64::MIN, f64::max);
        for (v_max, dt) in [(0.5, 0.2), (5.0, 1.0)] {
            let cfg = EnvConfig { v_max, dt, ..cfg() };
            let mut env = NavEnv::with_footprint(room.clone(), &cfg, 1, fp.clone());
            env.reset_to(Pose2::new(0.0, 0.0, 0.0), [3.0, 0.0]);
            let mut done = None;
            for _ in 0..40 {
                done = env.step(v_max, 0.0).done;
                if done.is_some() {
                    break;
                }
            }
            assert_eq!(done, Some(Outcome::Collision), "{} at {v_max} m/s", fp.name);
            let nose = env.pose().x + front;
            assert!(
                (0.99 - 1e-6..=0.99 + 0.02 + 1e-6).contains(&nose),
                "{}: nose at {nose}",
                fp.name
            );
        }
    }
}

/// A 1 m x 0.1 m rectangle turning in place beside a wall 0.3 m from its axle: it starts
/// and (after half a turn) would end parallel to the wall, clear of it, but its corners
/// sweep through the wall on the way. Checking only the end pose misses the contact.
#[test]
fn a_long_rectangle_turning_beside_a_wall_hits_it() {
    let mut spec = RoomSpec::empty("wall", 6.0);
    spec.obstacles.push(ObstacleSpec::Box {
        center: [0.0, 0.35],
        half_extents: [2.0, 0.05],
        angle: 0.0,
    });
    let room = Arc::new(Room::new(spec));
    let fp = Footprint::rectangle(1.0, 0.1);
    // ω_max·dt = π: one control step is half a turn.
    let cfg = EnvConfig { dt: 2.0, ..cfg() };
    let mut env = NavEnv::with_footprint(room.clone(), &cfg, 1, fp.clone());
    env.reset_to(Pose2::new(0.0, 0.0, 0.0), [2.0, -2.0]);
    assert!(!room.footprint_collides(&fp, Pose2::new(0.0, 0.0, PI)), "end pose is clear");
    let out = env.step(0.0, cfg.omega_max);
    assert_eq!(out.done, Some(Outcome::Collision));
    // Stopped at the first contact: a corner reaches y = 0.3 at yaw ≈ asin(0.25/0.51)−atan(0.1).
    let yaw = env.pose().yaw;
    let contact = (0.3f64 / 0.5f64.hypot(0.05)).asin() - (0.05f64 / 0.5).atan();
    assert!(yaw >= contact - 1e-9 && yaw <= contact + 0.02 / 0.5 + 1e-9, "yaw {yaw} vs {contact}");
    assert!(env.pose().position() == [0.0, 0.0]);
    // The same turn the other way is free (the wall is only on the left).
    let mut env = NavEnv::with_footprint(room, &cfg, 1, fp);
    env.reset_to(Pose2::new(0.0, -1.0, 0.0), [2.0, -2.0]);
    assert_eq!(env.step(0.0, -cfg.omega_max).done, None);
}

#[test]
fn footprints_sample_starts_with_their_clearance_and_stay_seeded() {
    let room = Room::builtin("env2").unwrap();
    let fp = Footprint::rectangle(0.8, 0.4)
        .with_cargo([ObstacleSpec::Circle { center: [-0.5, 0.0], radius: 0.15 }]);
    let cfg = cfg();
    let need = fp.bounding_radius() + cfg.spawn_clearance;
    let mut a = NavEnv::with_footprint(room.clone(), &cfg, 4, fp.clone());
    let mut b = NavEnv::with_footprint(room.clone(), &cfg, 4, fp.clone());
    for _ in 0..100 {
        for p in [a.start().position(), a.goal()] {
            assert!(room.clearance(p, 2.0) >= need - 1e-5, "{p:?}");
        }
        assert!(!room.footprint_collides(&fp, a.start()));
        assert_eq!((a.start(), a.goal()), (b.start(), b.goal()));
        a.reset();
        b.reset();
    }
    // Through the config as well.
    let via_cfg = EnvConfig { footprint: Some(fp.clone()), ..cfg.clone() };
    let c = NavEnv::new(room, &via_cfg, 4);
    assert_eq!(c.footprint(), &fp);
}

#[test]
fn spawn_regions_hold_starts_and_goals() {
    let mut spec = RoomSpec::empty("regions", 6.0);
    spec.spawn_regions = vec![
        crate::SpawnRegion {
            name: "west".into(),
            min: [-2.5, -2.5],
            max: [-1.5, 2.5],
            starts: true,
            goals: false,
        },
        crate::SpawnRegion {
            name: "east".into(),
            min: [1.5, -2.5],
            max: [2.5, 2.5],
            starts: false,
            goals: true,
        },
    ];
    let mut env = NavEnv::new(Arc::new(Room::new(spec)), &cfg(), 2);
    for _ in 0..100 {
        let (s, g) = (env.start().position(), env.goal());
        assert!((-2.5..=-1.5).contains(&s[0]) && (1.5..=2.5).contains(&g[0]), "{s:?} {g:?}");
        env.reset();
    }
}

/// The dynamic room's route driven straight at full speed: the first timed obstacle is in
/// the scan from step 8 on (not before), the rapier reference sees it too, and the robot
/// runs into it; the same seed and actions give byte-identical episodes.
#[test]
fn timed_obstacles_appear_in_scan_and_collision() {
    let room = Room::builtin("dynamic").unwrap();
    let route = room.spec().route("dynamic").unwrap().clone();
    let mut env = NavEnv::new(room.clone(), &cfg(), 1);
    env.reset_to(route.start_pose(), route.goals[0]);
    let ahead = |env: &NavEnv| env.scan()[270] as f64;
    let mut reference = vec![0.0f32; env.lidar().beams()];
    let mut hit = None;
    for k in 1..=40 {
        let before = ahead(&env);
        let out = env.step(0.5, 0.0);
        let y = env.pose().y;
        if k < 8 {
            assert_eq!(env.timed_active(), 0);
            assert!(ahead(&env) > 2.0 && (ahead(&env) - (before - 0.1)).abs() < 1e-3, "step {k}");
        } else if out.done.is_none() {
            assert!(env.timed_active() >= 1);
            // The disc at (0, −1), r 0.3: the beam just left of ahead meets it near y = −1.3.
            assert!((ahead(&env) - (-1.3 - y)).abs() < 1e-3, "step {k}: {} at y {y}", ahead(&env));
        }
        env.lidar().scan_reference_active(
            &room,
            env.pose(),
            env.timed_active(),
            None::<&mut Pcg64>,
            &mut reference,
        );
        for (i, (&f, &r)) in env.scan().iter().zip(&reference).enumerate() {
            assert!((f - r).abs() < 1e-4, "step {k}, beam {i}: {f} vs rapier {r}");
        }
        if out.done.is_some() {
            hit = Some((k, out.done));
            break;
        }
    }
    // The robot's front (y + 0.2) reaches the disc (y = −1.3) after 1.5 m: step 15.
    assert_eq!(hit, Some((15, Some(Outcome::Collision))));
    // Reset: the obstacles are gone again.
    env.reset_to(route.start_pose(), route.goals[0]);
    assert_eq!(env.timed_active(), 0);
    // Determinism in the dynamic room, with random starts and actions.
    let mut a = NavEnv::new(room.clone(), &cfg(), 8);
    let mut b = NavEnv::new(room, &cfg(), 8);
    for episode in 0..3 {
        let ea = run_episode(&mut a, &mut Pcg64::seed_from_u64(episode));
        let eb = run_episode(&mut b, &mut Pcg64::seed_from_u64(episode));
        assert_eq!(ea, eb, "episode {episode}");
        a.reset();
        b.reset();
    }
}

#[test]
fn an_obstacle_appearing_on_the_robot_is_a_collision() {
    let mut spec = RoomSpec::empty("drop", 6.0);
    spec.timed_obstacles.push(crate::TimedObstacle {
        at_step: 2,
        obstacle: ObstacleSpec::Circle { center: [0.5, 0.0], radius: 0.3 },
    });
    let mut env = NavEnv::new(Arc::new(Room::new(spec)), &cfg(), 1);
    env.reset_to(Pose2::new(0.0, 0.0, 0.0), [2.0, 2.0]);
    assert_eq!(env.step(0.0, 0.0).done, None);
    assert_eq!(env.step(0.0, 0.0).done, Some(Outcome::Collision), "appears at step 2");
}

#[test]
#[ignore = "benchmark; run with --release -- --ignored --nocapture"]
fn steps_per_second() {
    let room = Room::builtin("env2").unwrap();
    let mut env = NavEnv::new(room, &cfg(), 1);
    let mut obs = vec![0.0f32; env.obs_dim()];
    let mut actions = Pcg64::seed_from_u64(0);
    let n = 20_000;
    let t = std::time::Instant::now();
    for _ in 0..n {
        let out = env.step(actions.random_range(0.0..0.5), actions.random_range(-1.5..1.5));
        env.write_obs(&mut obs);
        if out.done.is_some() {
            env.reset();
        }
    }
    let s = t.elapsed().as_secs_f64();
    println!("single env: {:.0} steps/s ({:.1} µs/step)", n as f64 / s, s / n as f64 * 1e6);
    let (lidar, room, pose) = (env.lidar().clone(), env.room().clone(), env.pose());
    let mut scan = vec![0.0f32; lidar.beams()];
    let t = std::time::Instant::now();
    for _ in 0..n {
        lidar.scan(&room, pose, None::<&mut Pcg64>, &mut scan);
    }
    let s = t.elapsed().as_secs_f64();
    println!(
        "scan alone: {:.1} µs ({:.0} ns/beam)",
        s / n as f64 * 1e6,
        s / n as f64 * 1e9 / 540.0
    );
    let m = n / 10;
    let t = std::time::Instant::now();
    for _ in 0..m {
        lidar.scan_reference(&room, pose, None::<&mut Pcg64>, &mut scan);
    }
    let s = t.elapsed().as_secs_f64();
    println!("rapier reference scan: {:.1} µs", s / m as f64 * 1e6);
}

/// A 6 m room split at x = 0 by a wall with a 0.8 m gap at the centre.
fn split_room() -> Arc<Room> {
    let mut spec = RoomSpec::empty("split", 6.0);
    spec.wall_segments = vec![
        crate::WallSegment { from: [0.0, 3.0], to: [0.0, 0.4], thickness: Some(0.1) },
        crate::WallSegment { from: [0.0, -0.4], to: [0.0, -3.0], thickness: Some(0.1) },
    ];
    Arc::new(Room::new(spec))
}

#[test]
fn sampled_tasks_are_reachable_for_the_robots_size() {
    let room = split_room();
    let big = Footprint::circle(0.5);
    let mut env = NavEnv::with_footprint(room.clone(), &cfg(), 3, big.clone());
    for _ in 0..200 {
        env.reset();
        let (s, g) = (env.start().position(), env.goal());
        assert_eq!(s[0].signum(), g[0].signum(), "{s:?} -> {g:?} crosses the gap");
    }
    // Without the check the big robot gets impossible tasks across the gate.
    let off = EnvConfig { reachable_tasks: false, ..cfg() };
    let mut env = NavEnv::with_footprint(room.clone(), &off, 3, big);
    let crossing = (0..200)
        .filter(|_| {
            env.reset();
            env.start().x.signum() != env.goal()[0].signum()
        })
        .count();
    assert!(crossing > 20, "{crossing}");
    // The meta robot passes the gap: its tasks cross.
    let mut env = NavEnv::new(room, &cfg(), 3);
    let crossing = (0..200)
        .filter(|_| {
            env.reset();
            env.start().x.signum() != env.goal()[0].signum()
        })
        .count();
    assert!(crossing > 20, "{crossing}");
}

#[test]
fn distance_and_path_ratio_bounds_hold() {
    let room = split_room();
    let cfg = EnvConfig {
        min_start_goal_distance: 2.0,
        max_start_goal_distance: 3.0,
        max_path_ratio: 1.2,
        ..cfg()
    };
    let mut env = NavEnv::new(room.clone(), &cfg, 9);
    let reach = room.reach(0.2);
    for _ in 0..100 {
        env.reset();
        let (s, g) = (env.start().position(), env.goal());
        let d = (s[0] - g[0]).hypot(s[1] - g[1]);
        assert!((2.0..=3.0).contains(&d), "{d}");
        let path = reach.path_length(s, g, cfg.spawn_clearance).unwrap();
        assert!(path <= 1.2 * d, "{path} vs {d}");
    }
}

#[test]
fn reachability_changes_no_task_in_an_open_room() {
    // Every pair in an open room is reachable: the check draws nothing extra, so the seeded
    // episodes are those of a run without it.
    let room = Room::builtin("env3").unwrap();
    let off = EnvConfig { reachable_tasks: false, ..cfg() };
    let mut a = NavEnv::new(room.clone(), &cfg(), 11);
    let mut b = NavEnv::new(room, &off, 11);
    for _ in 0..100 {
        a.reset();
        b.reset();
        assert_eq!((a.start(), a.goal()), (b.start(), b.goal()));
    }
}

fn robust(r: crate::RobustnessConfig) -> EnvConfig {
    EnvConfig { robustness: r, ..cfg() }
}

#[test]
fn beam_dropout_loses_the_share_of_beams_it_says_as_serve_reads_them() {
    let room = Room::builtin("env0").unwrap();
    let r = crate::RobustnessConfig { beam_dropout: 0.3, ..Default::default() };
    let mut clean = NavEnv::new(room.clone(), &cfg(), 5);
    let mut noisy = NavEnv::new(room, &robust(r), 5);
    let (mut dropped, mut to_max, mut total) = (0, 0, 0);
    for _ in 0..20 {
        clean.reset();
        noisy.reset();
        // Robustness never changes the task.
        assert_eq!((clean.start(), clean.goal()), (noisy.start(), noisy.goal()));
        let (c, n) = (clean.scan(), noisy.scan());
        let nearest = c.iter().copied().fold(f32::INFINITY, f32::min);
        for (i, (&c, &n)) in c.iter().zip(n).enumerate() {
            total += 1;
            // Never a 0 m reading: the deployed pipeline never shows one for a lost return.
            assert!(n >= nearest, "beam {i} reads {n}, nearer than anything there ({nearest})");
            if c != n {
                dropped += 1;
                to_max += (n == 10.0) as usize;
                // Otherwise a neighbour's reading: some beam of the clean scan read it.
                assert!(n == 10.0 || clean.scan().contains(&n), "beam {i} reads {n}");
            }
        }
    }
    let share = dropped as f64 / total as f64;
    // A lost beam already at range_max, or whose nearer neighbour reads as it did, looks
    // unchanged: a bit under 0.3 in a closed room, up to sampling.
    assert!((0.2..0.33).contains(&share), "{share}");
    assert!(to_max as f64 / dropped as f64 > 0.5, "{to_max} of {dropped}");
    assert!(to_max < dropped, "some lost beams read a neighbour: {to_max} of {dropped}");
}

#[test]
fn latency_shows_the_scan_and_goal_of_k_steps_ago_and_the_command_as_sent() {
    let room = Room::builtin("env0").unwrap();
    let r = crate::RobustnessConfig { latency_steps: 2, ..Default::default() };
    let mut clean = NavEnv::new(room.clone(), &cfg(), 8);
    let mut late = NavEnv::new(room, &robust(r), 8);
    let d = clean.obs_dim();
    let mut past: Vec<Vec<f32>> = Vec::new();
    for t in 0..6 {
        let mut c = vec![0.0; d];
        let mut l = vec![0.0; d];
        clean.write_obs(&mut c);
        late.write_obs(&mut l);
        past.push(c.clone());
        let beams = d - 4;
        let (seen, command) = l.split_at(beams + obs::LINEAR_VELOCITY);
        let want = &past[t.max(2) - 2];
        assert_eq!(seen, &want[..beams + obs::LINEAR_VELOCITY], "scan and goal of step {t}");
        assert_eq!(command, &c[beams + obs::LINEAR_VELOCITY..], "the command as sent, step {t}");
        if t >= 3 {
            assert_ne!(seen, &c[..beams + obs::LINEAR_VELOCITY], "step {t} shows the past");
        }
        clean.step(0.3, 0.4);
        late.step(0.3, 0.4);
        assert_eq!(clean.pose(), late.pose(), "latency delays what is seen, not the motion");
    }
}

/// `env.latency_compensation`: with two cycles of latency the agent sees the delayed scan and
/// goal carried forward by the two commands since, close to what the robot sees now, where
/// without it the observation is two cycles old; the goal to a few millimetres (the command
/// is exactly what the robot drove), the scan beam by beam to 5 cm mostly.
#[test]
fn latency_compensation_carries_the_delayed_observation_to_the_pose_now() {
    let room = empty_room(6.0);
    let r = crate::RobustnessConfig { latency_steps: 2, ..Default::default() };
    let mut compensated = robust(r.clone());
    compensated.latency_compensation = true;
    let mut clean = NavEnv::new(room.clone(), &cfg(), 8);
    let mut late = NavEnv::new(room.clone(), &robust(r), 8);
    let mut carried = NavEnv::new(room, &compensated, 8);
    // Circling (0.625 m radius) by a wall: no collision, so the robot drives what it was sent.
    for env in [&mut clean, &mut late, &mut carried] {
        env.reset_to(Pose2::new(-1.5, -1.0, 0.0), [2.0, 1.5]);
    }
    let d = clean.obs_dim();
    let beams = d - 4;
    let (mut c, mut l, mut k) = (vec![0.0; d], vec![0.0; d], vec![0.0; d]);
    let (mut close_late, mut close_carried, mut total) = (0, 0, 0);
    for t in 0..8 {
        clean.write_obs(&mut c);
        late.write_obs(&mut l);
        carried.write_obs(&mut k);
        // Commands the same: the last one sent.
        assert_eq!(k[beams + obs::LINEAR_VELOCITY..], c[beams + obs::LINEAR_VELOCITY..]);
        if t >= 2 {
            let goal = beams + obs::GOAL_DISTANCE;
            assert!((k[goal] - c[goal]).abs() < 1e-3, "step {t}: {} vs {}", k[goal], c[goal]);
            assert!((l[goal] - c[goal]).abs() > 0.05, "step {t}: the delayed goal differs");
            let angle = beams + obs::GOAL_ANGLE;
            assert!((k[angle] - c[angle]).abs() < 1e-3, "step {t}: {} vs {}", k[angle], c[angle]);
            for i in 0..beams {
                total += 1;
                close_late += ((l[i] - c[i]).abs() <= 0.05) as usize;
                close_carried += ((k[i] - c[i]).abs() <= 0.05) as usize;
            }
        }
        for env in [&mut clean, &mut late, &mut carried] {
            env.step(0.5, 0.8);
        }
        assert_eq!(clean.pose(), carried.pose(), "compensation changes what is seen only");
    }
    let share = |n: usize| n as f64 / total as f64;
    assert!(
        share(close_carried) >= 0.9,
        "{} of the carried beams within 5 cm",
        share(close_carried)
    );
    assert!(share(close_late) < share(close_carried) - 0.3, "{} delayed", share(close_late));
}

#[test]
fn actuation_noise_moves_the_robot_off_the_command_and_jitter_stretches_steps() {
    let room = empty_room(8.0);
    let a = crate::RobustnessConfig { actuation_noise_std: [0.05, 0.2], ..Default::default() };
    let mut clean = NavEnv::new(room.clone(), &cfg(), 2);
    let mut noisy = NavEnv::new(room.clone(), &robust(a), 2);
    clean.reset_to(Pose2::new(-3.0, 0.0, 0.0), [3.0, 0.0]);
    noisy.reset_to(Pose2::new(-3.0, 0.0, 0.0), [3.0, 0.0]);
    for _ in 0..5 {
        clean.step(0.3, 0.0);
        noisy.step(0.3, 0.0);
    }
    assert_eq!(clean.pose().y, 0.0);
    assert!(noisy.pose().y.abs() > 1e-4, "{:?}", noisy.pose());
    // The command seen in the observation is what the policy asked for.
    assert_eq!(noisy.velocity(), (0.3, 0.0));

    let j = crate::RobustnessConfig { dt_jitter: 0.2, ..Default::default() };
    let mut env = NavEnv::new(room, &robust(j), 3);
    env.reset_to(Pose2::new(-3.0, 0.0, 0.0), [3.0, 0.0]);
    let mut lengths = Vec::new();
    for _ in 0..20 {
        let x = env.pose().x;
        env.step(0.5, 0.0);
        lengths.push(env.pose().x - x);
    }
    assert!(lengths.iter().all(|&l| (0.08 - 1e-9..=0.12 + 1e-9).contains(&l)), "{lengths:?}");
    let spread =
        lengths.iter().cloned().fold(0.0, f64::max) - lengths.iter().cloned().fold(1.0, f64::min);
    assert!(spread > 0.02, "{lengths:?}");
}

#[test]
fn randomized_robustness_draws_each_episode_anew() {
    let r = crate::RobustnessConfig {
        randomize: Some(crate::RandomizeConfig {
            noise_std: [0.0, 0.03],
            latency_steps: [0, 1],
            ..Default::default()
        }),
        ..Default::default()
    };
    let mut env = NavEnv::new(Room::builtin("env0").unwrap(), &robust(r), 4);
    let mut sigmas = Vec::new();
    let mut latencies = [0; 2];
    for _ in 0..40 {
        env.reset();
        let p = env.perturbation();
        assert!((0.0..=0.03).contains(&p.noise_std));
        sigmas.push(p.noise_std);
        latencies[p.latency_steps as usize] += 1;
    }
    sigmas.dedup();
    assert!(sigmas.len() > 30);
    assert!(latencies[0] > 5 && latencies[1] > 5, "{latencies:?}");
}

#[test]
fn the_omega_change_penalty_charges_each_change_of_the_angular_command() {
    let room = empty_room(8.0);
    let mut cfg = cfg();
    let run = |cfg: &EnvConfig| {
        let mut env = NavEnv::new(room.clone(), cfg, 1);
        env.reset_to(Pose2::new(-3.0, 0.0, 0.0), [3.0, 0.0]);
        [0.5, -0.5, -0.5].map(|w| env.step(0.2, w).reward as f64)
    };
    let plain = run(&cfg);
    cfg.reward.omega_change = 0.1;
    let smooth = run(&cfg);
    // First step free, then |Δω| = 1.0 and 0.
    assert_eq!(smooth[0], plain[0]);
    assert!((plain[1] - smooth[1] - 0.1).abs() < 1e-6, "{plain:?} {smooth:?}");
    assert_eq!(smooth[2], plain[2]);
}

/// A 6 m room split at x = 0 by a wall with a 0.8 m door near the top (y = 2).
fn door_room() -> Arc<Room> {
    let mut spec = RoomSpec::empty("door", 6.0);
    spec.wall_segments = vec![
        crate::WallSegment { from: [0.0, 3.0], to: [0.0, 2.4], thickness: Some(0.1) },
        crate::WallSegment { from: [0.0, 1.6], to: [0.0, -3.0], thickness: Some(0.1) },
    ];
    Arc::new(Room::new(spec))
}

fn with_subgoals() -> EnvConfig {
    EnvConfig { subgoals: Some(crate::subgoal::SubgoalConfig::default()), ..cfg() }
}

/// Heads for the goal the observation gives: turn towards it, drive when roughly facing it.
fn seek(obs: &[f32]) -> (f64, f64) {
    let a = obs[obs.len() - 3] as f64;
    (if a.abs() < 0.3 { 0.5 } else { 0.0 }, (2.0 * a).clamp(-FRAC_PI_2, FRAC_PI_2))
}

fn drive(env: &mut NavEnv) -> Outcome {
    let mut obs = vec![0.0; env.obs_dim()];
    loop {
        env.write_obs(&mut obs);
        let (v, w) = env.shim_command().unwrap_or_else(|| seek(&obs));
        if let Some(o) = env.step(v, w).done {
            return o;
        }
    }
}

#[test]
fn with_subgoals_a_goal_behind_a_wall_is_reached_through_the_door() {
    let (start, goal) = (Pose2::new(-2.0, -1.0, 0.0), [2.0, -1.0]);
    // Mapless, the seeker drives straight into the wall.
    let mut env = NavEnv::new(door_room(), &cfg(), 1);
    env.reset_to(start, goal);
    assert_eq!(drive(&mut env), Outcome::Collision);
    assert!(env.route_stats().is_none() && env.planned_path().is_none());
    // Following the plan it goes through the door.
    let mut env = NavEnv::new(door_room(), &with_subgoals(), 1);
    env.reset_to(start, goal);
    let path = env.planned_path().unwrap().clone();
    assert!(path.length_m > 2.0 * 2f64.hypot(3.0), "{path:?}");
    let mut obs = vec![0.0; env.obs_dim()];
    env.write_obs(&mut obs);
    let sub = env.observed_goal();
    assert!(dist(sub, start.position()) <= 1.5 + 1e-9 && sub != goal, "{sub:?}");
    assert!((obs[obs.len() - 4] as f64 - dist(sub, start.position())).abs() < 1e-5);
    assert_eq!(drive(&mut env), Outcome::Success);
    let stats = env.route_stats().unwrap();
    assert_eq!(stats.planned_length_m, Some(path.length_m));
    assert!(stats.follow && !stats.blocked);
}

#[test]
fn with_subgoals_progress_is_paid_along_the_path() {
    // Facing the goal straight through the wall: driving at it shortens the straight line
    // but not the path, which goes up to the door first.
    let (start, goal) = (Pose2::new(-2.0, -1.0, 0.0), [2.0, -1.0]);
    let no_shim = crate::subgoal::SubgoalConfig {
        rotation_shim: false,
        ..crate::subgoal::SubgoalConfig::default()
    };
    let mut env = NavEnv::new(door_room(), &EnvConfig { subgoals: Some(no_shim), ..cfg() }, 1);
    env.reset_to(start, goal);
    let into_the_wall = env.step(0.5, 0.0).reward;
    let mut plain = NavEnv::new(door_room(), &cfg(), 1);
    plain.reset_to(start, goal);
    let mapless = plain.step(0.5, 0.0).reward;
    assert!((mapless - 0.19).abs() < 1e-6);
    assert!(into_the_wall < 0.1, "{into_the_wall}");
    // Towards the door: paid nearly in full.
    let mut env = NavEnv::new(door_room(), &EnvConfig { subgoals: Some(no_shim2()), ..cfg() }, 1);
    let up = Pose2::new(-2.0, -1.0, (3.0f64).atan2(2.0));
    env.reset_to(up, goal);
    let along = env.step(0.5, 0.0).reward;
    assert!(along > 0.15, "{along}");
}

fn no_shim2() -> crate::subgoal::SubgoalConfig {
    crate::subgoal::SubgoalConfig { rotation_shim: false, ..Default::default() }
}

#[test]
fn the_rotation_shim_turns_a_robot_facing_away_and_mapless_follow_keeps_the_goal() {
    let mut env = NavEnv::new(door_room(), &with_subgoals(), 1);
    env.reset_to(Pose2::new(-2.0, -1.0, -2.0), [2.0, -1.0]);
    let (v, w) = env.shim_command().unwrap();
    assert_eq!(v, 0.0);
    assert_eq!(w.abs(), FRAC_PI_2);
    // follow = false: the plan is made for the reports, the agent sees the goal.
    let report_only = crate::subgoal::SubgoalConfig { follow: false, ..Default::default() };
    let mut env = NavEnv::new(door_room(), &EnvConfig { subgoals: Some(report_only), ..cfg() }, 1);
    env.reset_to(Pose2::new(-2.0, -1.0, -2.0), [2.0, -1.0]);
    assert_eq!(env.shim_command(), None);
    assert_eq!(env.observed_goal(), [2.0, -1.0]);
    assert!(env.route_stats().unwrap().planned_length_m.unwrap() > 7.0);
}

#[test]
fn a_robot_too_big_for_the_door_is_blocked_and_heads_for_the_goal() {
    let big = Footprint::circle(0.45);
    let mut env = NavEnv::with_footprint(door_room(), &with_subgoals(), 1, big);
    env.reset_to(Pose2::new(-2.0, -1.0, 0.0), [2.0, -1.0]);
    let stats = env.route_stats().unwrap();
    assert!(stats.blocked && stats.planned_length_m.is_none());
    assert_eq!(env.observed_goal(), [2.0, -1.0]);
}

#[test]
fn follow_share_mixes_followed_and_mapless_episodes_without_changing_the_tasks() {
    let half = crate::subgoal::SubgoalConfig { follow_share: 0.5, ..no_shim2() };
    let mixed_cfg = EnvConfig { subgoals: Some(half), ..cfg() };
    let mut mixed = NavEnv::new(door_room(), &mixed_cfg, 7);
    let mut all = NavEnv::new(door_room(), &EnvConfig { subgoals: Some(no_shim2()), ..cfg() }, 7);
    let mut followed = 0;
    for _ in 0..200 {
        mixed.reset();
        all.reset();
        // The same seed draws the same tasks: the share draws from another stream.
        assert_eq!(mixed.goal(), all.goal());
        let stats = mixed.route_stats().unwrap();
        if stats.follow {
            followed += 1;
        } else {
            // A mapless episode: the agent sees the final goal.
            assert_eq!(mixed.observed_goal(), mixed.goal());
        }
        assert!(all.route_stats().unwrap().follow);
    }
    assert!((70..=130).contains(&followed), "{followed} of 200 followed");
    let bad = crate::subgoal::SubgoalConfig { follow_share: 1.5, ..Default::default() };
    assert_eq!(bad.check().unwrap_err().0, "env.subgoals.follow_share");
}

/// `[env.dvst]`: an episode of a varied robot shows the meta agent what DVST would (lengths
/// over μ, clamped to the meta LiDAR's range), moves as DVST's policy transfer commands, and
/// pays progress in the meta robot's units; evaluation routes drive the meta robot.
#[test]
fn a_varied_robot_episode_goes_through_dvst() {
    use crate::transfer::{VelocityBounds, transfer_observation, transfer_policy};
    let room = Room::builtin("env1").unwrap();
    let varied = EnvConfig {
        dvst: Some(crate::DvstTrainingConfig { radius_range: [0.5, 0.5], share: 1.0 }),
        ..cfg()
    };
    let big = EnvConfig { robot_radius: 0.5, ..cfg() };
    let mut env = NavEnv::new(room.clone(), &varied, 4);
    assert_eq!((env.robot_radius(), env.dvst_scale()), (0.5, 2.5));
    // The same robot simulated plainly at its own size, from the same pose.
    let mut plain = NavEnv::new(room, &big, 4);
    let (start, goal) = (env.pose(), env.goal());
    plain.reset_to(start, goal);
    let bounds = VelocityBounds { v_max: 0.5, omega_max: std::f64::consts::FRAC_PI_2 };
    let d = env.obs_dim();
    let (mut seen, mut raw, mut want) = (vec![0.0; d], vec![0.0; d], vec![0.0; d]);
    for (t, &(v, w)) in [(0.4, 0.3), (0.1, -1.2), (0.5, 0.0), (0.0, 1.0)].iter().enumerate() {
        env.write_obs(&mut seen);
        plain.write_obs(&mut raw);
        transfer_observation(&raw, 540, 2.5, Some([0.0, 10.0]), &mut want);
        assert_eq!(seen, want, "observation of step {t}");
        let (vs, ws) = transfer_policy(v, w, 2.5, bounds);
        let a = env.step(v, w);
        let b = plain.step(vs, ws);
        assert_eq!(env.pose(), plain.pose(), "step {t} moves as DVST commands");
        assert_eq!(env.velocity(), (vs, ws));
        if a.done.is_none() {
            let progress_b = b.reward + 0.01; // the paper's time penalty
            let progress_a = a.reward + 0.01;
            assert!((progress_a * 2.5 - progress_b).abs() < 1e-5, "{a:?} {b:?}");
        }
    }
    env.reset_to(start, goal);
    assert_eq!((env.robot_radius(), env.dvst_scale()), (0.2, 1.0), "routes drive the meta robot");

    // A share of the episodes, the rest the meta robot; a given footprint never varies.
    let half = EnvConfig {
        dvst: Some(crate::DvstTrainingConfig { radius_range: [0.3, 0.6], share: 0.5 }),
        ..cfg()
    };
    let mut env = NavEnv::new(Room::builtin("env1").unwrap(), &half, 9);
    let mut varied_count = 0;
    for _ in 0..200 {
        env.reset();
        let mu = env.dvst_scale();
        if mu != 1.0 {
            varied_count += 1;
            assert!((1.5..=3.0).contains(&mu), "{mu}");
            assert!((env.robot_radius() - 0.2 * mu).abs() < 1e-12);
        } else {
            assert_eq!(env.robot_radius(), 0.2);
        }
    }
    assert!((70..=130).contains(&varied_count), "{varied_count} of 200");
    let fp = Footprint::circle(0.2);
    let named = NavEnv::with_footprint(Room::builtin("env1").unwrap(), &half, 9, fp);
    assert_eq!(named.dvst_scale(), 1.0);
}

#[test]
fn long_tasks_are_drawn_where_the_planner_reaches() {
    // A 30 m hall split at x = 0 with a 0.75 m door: 0.35 m to spare for a 0.2 m robot, which
    // the task-sampling raster's 7.5 cm conservative cells call shut and the planner's 2.5 cm
    // ones do not.
    let mut spec = RoomSpec::empty("hall", 30.0);
    spec.wall_segments = vec![
        crate::WallSegment { from: [0.0, 15.0], to: [0.0, 0.375], thickness: Some(0.1) },
        crate::WallSegment { from: [0.0, -0.375], to: [0.0, -15.0], thickness: Some(0.1) },
    ];
    let room = Arc::new(Room::new(spec));
    assert!(!room.reach(0.2).connected([-3.0, 0.0], [3.0, 0.0], 0.1));
    assert!(room.planning_reach(0.2).connected([-3.0, 0.0], [3.0, 0.0], 0.1));
    let long = EnvConfig {
        min_start_goal_distance: 5.0,
        max_start_goal_distance: 10.0,
        max_path_ratio: 0.0,
        ..with_subgoals()
    };
    let mut env = NavEnv::new(room.clone(), &long, 3);
    let across = (0..200)
        .filter(|_| {
            env.reset();
            let (a, b) = (env.start().position(), env.goal());
            assert!(!env.route_stats().unwrap().blocked, "{a:?} -> {b:?} was drawn unplannable");
            (a[0] < 0.0) != (b[0] < 0.0)
        })
        .count();
    assert!(across >= 10, "{across} of 200 long tasks through the door");
    // Local tasks keep the sampling raster: none goes through.
    let local = EnvConfig { min_start_goal_distance: 5.0, max_start_goal_distance: 10.0, ..cfg() };
    let mut env = NavEnv::new(room, &local, 3);
    for _ in 0..100 {
        env.reset();
        assert_eq!(env.start().position()[0] < 0.0, env.goal()[0] < 0.0);
    }
}

#[test]
fn a_long_route_gets_time_in_proportion_to_its_path() {
    // The 30 m hall of the test above, long tasks; a robot that never moves times out at the
    // episode's own limit.
    let mut spec = RoomSpec::empty("hall", 30.0);
    spec.obstacles.push(ObstacleSpec::Box {
        center: [0.0, 0.0],
        half_extents: [0.1, 12.0],
        angle: 0.0,
    });
    let room = Arc::new(Room::new(spec));
    let long = |factor: f64| EnvConfig {
        min_start_goal_distance: 8.0,
        max_start_goal_distance: 10.0,
        max_path_ratio: 0.0,
        subgoals: Some(crate::subgoal::SubgoalConfig {
            time_limit_factor: factor,
            ..Default::default()
        }),
        ..cfg()
    };
    let mut fixed = NavEnv::new(room.clone(), &long(0.0), 5);
    fixed.reset();
    assert_eq!(fixed.step_limit, fixed.cfg.max_steps);
    let mut env = NavEnv::new(room, &long(4.0), 5);
    let mut longer = 0;
    for _ in 0..20 {
        env.reset();
        let len = env.route_stats().unwrap().planned_length_m.unwrap();
        let want = (4.0 * len / (env.cfg.v_max * env.cfg.dt)).ceil() as u32;
        assert_eq!(env.step_limit, want.max(env.cfg.max_steps), "path {len} m");
        longer += usize::from(env.step_limit > env.cfg.max_steps);
    }
    assert!(longer > 0, "some routes round the wall need more than max_steps");
    let limit = env.step_limit;
    let mut steps = 0;
    let outcome = loop {
        steps += 1;
        if let Some(o) = env.step(0.0, 0.0).done {
            break o;
        }
    };
    assert_eq!((outcome, steps), (Outcome::Timeout, limit));
}

#[test]
fn a_geodesic_reward_pays_for_the_way_round_a_wall_not_for_the_wall() {
    // A wall down x = 0 from the top to y = -1.5; the goal behind it.
    let mut spec = RoomSpec::empty("way-round", 6.0);
    let t = Some(0.1);
    spec.wall_segments =
        vec![crate::spec::WallSegment { from: [0.0, 3.0], to: [0.0, -1.5], thickness: t }];
    let room = Arc::new(Room::new(spec));
    let (start_at, goal) = ([-1.5, 1.0], [1.5, 1.0]);
    let run = |geodesic: bool, heading: f64| {
        let mut c = cfg();
        c.reward.geodesic_progress = geodesic;
        let mut env = NavEnv::new(room.clone(), &c, 1);
        env.reset_to(Pose2::new(start_at[0], start_at[1], heading), goal);
        (0..5).map(|_| env.step(0.5, 0.0).reward as f64).sum::<f64>()
    };
    // Half a metre straight at the goal (and at the wall) against half a metre down towards
    // the end of the wall: the straight line pays the first (+0.95 against −0.13); the way
    // round pays the second (it shortens the way by ~0.43 m, the first by ~0.2 m).
    let (at_wall, down) = (0.0, -FRAC_PI_2);
    let (straight_at_wall, straight_down) = (run(false, at_wall), run(false, down));
    assert!(straight_at_wall > 0.9 && straight_down < 0.0, "{straight_at_wall} {straight_down}");
    let (geodesic_at_wall, geodesic_down) = (run(true, at_wall), run(true, down));
    assert!(
        geodesic_down > geodesic_at_wall + 0.3,
        "down {geodesic_down} against at the wall {geodesic_at_wall}"
    );
    assert!((geodesic_down - 0.81).abs() < 0.1, "{geodesic_down}");
    // Evaluations keep the paper's reward.
    let mut c = cfg();
    c.reward.geodesic_progress = true;
    assert!(!c.clean().reward.geodesic_progress);
}
