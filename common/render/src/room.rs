//! A room's walls and obstacles, filled, in a [`WorldView`].

use super::{Canvas, Rgba, WorldView};
use dvnav_sim::{ObstacleSpec, RoomSpec};

/// Wall colour.
pub const WALL: Rgba = Rgba::hex(0x6b6b75);
/// Obstacle colour.
pub const OBSTACLE: Rgba = Rgba::hex(0xc07a3a);
/// Floor colour.
pub const FLOOR: Rgba = Rgba::hex(0xf7f5f0);

/// Corners of a box obstacle, counter-clockwise.
fn box_corners(center: [f64; 2], half: [f64; 2], angle: f64) -> [[f64; 2]; 4] {
    let (s, c) = angle.sin_cos();
    [[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]].map(|[sx, sy]| {
        let (x, y) = (sx * half[0], sy * half[1]);
        [center[0] + c * x - s * y, center[1] + s * x + c * y]
    })
}

/// Draws one convex shape (a compound's parts one by one).
pub fn draw_shape(canvas: &mut Canvas, view: &WorldView, shape: &ObstacleSpec, color: Rgba) {
    shape.for_each_primitive(&mut |o| match o {
        ObstacleSpec::Box { center, half_extents, angle } => {
            let pts: Vec<_> =
                box_corners(*center, *half_extents, *angle).iter().map(|&p| view.px(p)).collect();
            canvas.fill_polygon(&pts, color);
        }
        ObstacleSpec::Circle { center, radius } => {
            let (x, y) = view.px(*center);
            canvas.fill_circle(x, y, (*radius as f32) * view.scale(), color);
        }
        ObstacleSpec::Polygon { points } => {
            let pts: Vec<_> = points.iter().map(|&p| view.px(p)).collect();
            canvas.fill_polygon(&pts, color);
        }
        // for_each_primitive hands out no compounds.
        ObstacleSpec::Compound { .. } => {}
    });
}

/// Draws the floor (the room's square), every wall ([`RoomSpec::walls`]: the square's sides
/// and any wall segments) and every obstacle.
pub fn draw_room(canvas: &mut Canvas, view: &WorldView, room: &RoomSpec) {
    let h = 0.5 * room.side;
    let floor: Vec<(f32, f32)> =
        [[-h, -h], [h, -h], [h, h], [-h, h]].iter().map(|&p| view.px(p)).collect();
    canvas.fill_polygon(&floor, FLOOR);
    for w in room.walls().iter() {
        draw_shape(canvas, view, w, WALL);
    }
    for o in &room.obstacles {
        draw_shape(canvas, view, o, OBSTACLE);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::WHITE;

    #[test]
    fn walls_floor_and_each_obstacle_shape_are_drawn_where_they_are() {
        let room = RoomSpec {
            wall_thickness: 0.5,
            obstacles: vec![
                ObstacleSpec::Box { center: [2.0, 2.0], half_extents: [1.0, 0.5], angle: 0.0 },
                ObstacleSpec::Circle { center: [-2.0, -2.0], radius: 1.0 },
                ObstacleSpec::Polygon { points: vec![[2.0, -3.0], [4.0, -3.0], [3.0, -1.0]] },
            ],
            ..RoomSpec::empty("t", 10.0)
        };
        // 11 m shown on 110 px: 10 px per metre, origin at (55, 55).
        let view = WorldView { left: 0.0, top: 0.0, size: 110.0, center: [0.0, 0.0], side: 11.0 };
        let mut c = Canvas::new(110, 110, WHITE).unwrap();
        draw_room(&mut c, &view, &room);
        let at = |p: [f64; 2]| {
            let (x, y) = view.px(p);
            c.pixel(x as u32, y as u32).unwrap()
        };
        assert_eq!(at([0.0, 5.2]), WALL, "top wall");
        assert_eq!(at([-5.2, 0.0]), WALL, "left wall");
        assert_eq!(at([0.0, 0.0]), FLOOR);
        assert_eq!(at([2.8, 2.3]), OBSTACLE, "inside the box");
        assert_eq!(at([2.0, 2.8]), FLOOR, "above the box");
        assert_eq!(at([-2.0, -2.0]), OBSTACLE, "disc centre");
        assert_eq!(at([-2.0, -0.7]), FLOOR, "outside the disc");
        assert_eq!(at([3.0, -2.5]), OBSTACLE, "inside the triangle");
        assert_eq!(at([3.8, -1.3]), FLOOR, "beside the triangle's apex");
        assert_eq!(at([5.45, 5.45]), WALL, "corner");
    }

    #[test]
    fn rotated_boxes_rotate() {
        let c = box_corners([0.0, 0.0], [2.0, 1.0], std::f64::consts::FRAC_PI_2);
        // (2, 1) half-extents turned by 90°: the long side is vertical.
        let max_y = c.iter().map(|p| p[1]).fold(f64::MIN, f64::max);
        let max_x = c.iter().map(|p| p[0]).fold(f64::MIN, f64::max);
        assert!((max_y - 2.0).abs() < 1e-12 && (max_x - 1.0).abs() < 1e-12);
    }
}
