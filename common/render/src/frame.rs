//! One moment of an environment, as Gymnasium's `rgb_array` render mode shows it: the room, the
//! timed obstacles present now, the LiDAR's rays (every few beams), the goal with its tolerance,
//! and the robot's footprint with a heading mark. No title or legend: a frame is a video frame.

use crate::room::{OBSTACLE, draw_room, draw_shape};
use crate::room_map::{ROBOT, outline};
use crate::{Canvas, INK, Rgba, WHITE, WorldView};
use dvnav_sim::{NavEnv, RoomSpec};

/// The goal marker and its tolerance disc.
pub const GOAL: Rgba = Rgba::hex(0x2ca02c);
/// LiDAR rays.
pub const RAY: Rgba = Rgba::hex(0xd62728);

/// Rays drawn: every beam would be a solid fan at 540 beams.
const RAYS: usize = 60;

/// The whole room, walls included, on a `size`-pixel square.
pub fn frame_view(spec: &RoomSpec, size: u32) -> WorldView {
    WorldView {
        left: 0.0,
        top: 0.0,
        size: size as f32,
        center: [0.0, 0.0],
        side: spec.side + 2.0 * spec.wall_thickness + 0.3,
    }
}

/// Draws `env` as it is now on a `size` x `size` canvas.
pub fn render_frame(env: &NavEnv, size: u32) -> anyhow::Result<Canvas> {
    let mut canvas = Canvas::new(size, size, WHITE)?;
    let room = env.room();
    let spec = room.spec();
    let view = frame_view(spec, size);
    draw_room(&mut canvas, &view, spec);
    // The room sorts its timed obstacles by the step they appear at; `timed_active` counts a
    // prefix of that order.
    let mut timed: Vec<_> = spec.timed_obstacles.iter().collect();
    timed.sort_by_key(|t| t.at_step);
    for t in timed.iter().take(env.timed_active()) {
        draw_shape(&mut canvas, &view, &t.obstacle, OBSTACLE);
    }

    let pose = env.pose();
    let goal = env.goal();
    let (gx, gy) = view.px(goal);
    let tolerance = (env.config().goal_tolerance as f32 * view.scale()).max(3.0);
    canvas.fill_circle(gx, gy, tolerance, GOAL.alpha(60));
    canvas.fill_circle(gx, gy, 3.0, GOAL);

    let origin = view.px(pose.position());
    let scan = env.scan();
    let angles = env.lidar().beam_angles();
    let every = scan.len().div_ceil(RAYS).max(1);
    for (range, angle) in scan.iter().zip(angles).step_by(every) {
        let a = pose.yaw + angle;
        let r = f64::from(*range);
        let end = view.px([pose.x + r * a.cos(), pose.y + r * a.sin()]);
        canvas.stroke_polyline(&[origin, end], false, 1.0, RAY.alpha(110));
    }

    for part in env.footprint().at(pose) {
        draw_shape(&mut canvas, &view, &part, ROBOT.alpha(150));
        for ring in outline(&view, &part) {
            canvas.stroke_polyline(&ring, true, 1.5, ROBOT);
        }
    }
    let nose = env.robot_radius().max(0.1);
    let tip = view.px([pose.x + nose * pose.yaw.cos(), pose.y + nose * pose.yaw.sin()]);
    canvas.stroke_polyline(&[origin, tip], false, 2.0, INK);
    Ok(canvas)
}

#[cfg(test)]
mod tests {
    use super::*;
    use dvnav_sim::{EnvConfig, Room};

    #[test]
    fn the_frame_shows_the_robot_at_its_pose_and_the_goal() {
        let env = NavEnv::new(Room::builtin("env0").unwrap(), &EnvConfig::default(), 3);
        let size = 200;
        let c = render_frame(&env, size).unwrap();
        assert_eq!(c.rgb().len(), (size * size * 3) as usize);
        let view = frame_view(env.room().spec(), size);
        let at = |p: [f64; 2]| {
            let (x, y) = view.px(p);
            c.pixel(x as u32, y as u32).unwrap()
        };
        // Behind the axle: the heading mark covers the axle's own pixel.
        let p = env.pose();
        let robot = at([p.x - 0.1 * p.yaw.cos(), p.y - 0.1 * p.yaw.sin()]);
        assert!(robot.2 > robot.0 && robot.2 > robot.1, "blue robot at its pose: {robot:?}");
        let goal = at(env.goal());
        assert!(goal.1 > goal.0 && goal.1 > goal.2, "green goal: {goal:?}");
    }
}
