"""ROS 2 messages to and from dvnav's controller protocol (dvnav.controller.v1), as plain
functions: no rclpy here, so the same code runs on a robot with ROS 2's message classes and in
the tests with those of the `rosbags` package (same field names, same types)."""

from __future__ import annotations

import math
from dataclasses import dataclass


def yaw_of(q) -> float:
    """The heading (rad) of a geometry_msgs/Quaternion: its rotation about z."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def wrap(a: float) -> float:
    """An angle in (-pi, pi]."""
    return math.atan2(math.sin(a), math.cos(a))


def stamp_seconds(header) -> float:
    """A std_msgs/Header's stamp in seconds."""
    return header.stamp.sec + header.stamp.nanosec * 1e-9


@dataclass(frozen=True)
class RobotState:
    """Where the robot is and how it moves, from nav_msgs/Odometry: the pose in the odometry
    frame (m, m, rad), the velocity in the robot frame (m/s, rad/s)."""

    x: float
    y: float
    yaw: float
    v: float
    omega: float


def robot_state(odom) -> RobotState:
    p = odom.pose.pose
    t = odom.twist.twist
    return RobotState(
        x=float(p.position.x),
        y=float(p.position.y),
        yaw=yaw_of(p.orientation),
        v=float(t.linear.x),
        omega=float(t.angular.z),
    )


def goal_xy(goal_pose) -> tuple[float, float]:
    """A geometry_msgs/PoseStamped goal's position, taken in the odometry frame."""
    return float(goal_pose.pose.position.x), float(goal_pose.pose.position.y)


def goal_relative(goal: tuple[float, float], state: RobotState) -> tuple[float, float]:
    """The goal as the controller wants it: distance (m) and bearing in the robot frame (rad,
    left positive)."""
    dx, dy = goal[0] - state.x, goal[1] - state.y
    return math.hypot(dx, dy), wrap(math.atan2(dy, dx) - state.yaw)


def laser_scan(pb2, scan):
    """A sensor_msgs/LaserScan as the controller's LaserScan: any count, any field of view,
    either direction; +inf, -inf and NaN are sent as they are (REP 117: the server reads them)."""
    return pb2.LaserScan(
        angle_min=float(scan.angle_min),
        angle_increment=float(scan.angle_increment),
        range_min=float(scan.range_min),
        range_max=float(scan.range_max),
        ranges=[float(r) for r in scan.ranges],
    )


def path_points(path) -> list[tuple[float, float]]:
    """A nav_msgs/Path's positions (m), in its order: the route the controller follows."""
    return [(float(p.pose.position.x), float(p.pose.position.y)) for p in path.poses]


def occupancy_grid_map(grid) -> tuple[str, bytes]:
    """A nav_msgs/OccupancyGrid as map_server files: the YAML text and a PGM image, cells as
    map_saver writes them (occupancy >= 65: black, 0-25: white, unknown or between: grey), rows
    flipped (the grid's first row is its bottom, an image's its top)."""
    info = grid.info
    w, h = int(info.width), int(info.height)
    data = list(grid.data)
    if len(data) != w * h:
        raise ValueError(f"OccupancyGrid has {len(data)} cells for {w} x {h}")

    def pixel(v: int) -> int:
        if v < 0:
            return 205
        if v >= 65:
            return 0
        if v <= 25:
            return 254
        return 205

    rows = [bytes(pixel(int(v)) for v in data[r * w:(r + 1) * w]) for r in range(h)]
    pgm = f"P5\n{w} {h}\n255\n".encode() + b"".join(reversed(rows))
    o = info.origin
    yaml = (
        f"image: map.pgm\nresolution: {float(info.resolution)!r}\n"
        f"origin: [{float(o.position.x)!r}, {float(o.position.y)!r}, {yaw_of(o.orientation)!r}]\n"
        "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    return yaml, pgm


def set_route_request(pb2, robot_id: str, points):
    """SetRoute for `points`, or one that clears the robot's route when there are none."""
    if not points:
        return pb2.SetRouteRequest(robot_id=robot_id, clear=True)
    return pb2.SetRouteRequest(
        robot_id=robot_id, poses=[pb2.Pose2D(x=x, y=y, yaw=0.0) for x, y in points]
    )


MAX_SCAN_AGE_S = 2.0


def act_request(
    pb2,
    scan,
    state: RobotState,
    goal,
    robot_id: str = "",
    expected_version: int = 0,
    pose=None,
    scan_age_s: float = 0.0,
):
    """One control cycle's ActRequest from the latest scan, odometry state and goal; with a
    route, `pose` (x, y, yaw in the route's frame) goes with it. `scan_age_s`: how long ago the
    scan was taken (clamped to the server's 0-2 s), so that the server carries it forward."""
    distance, angle = goal_relative(goal, state)
    extra = {} if pose is None else {"pose": pb2.Pose2D(x=pose[0], y=pose[1], yaw=pose[2])}
    return pb2.ActRequest(
        **extra,
        laser_scan=laser_scan(pb2, scan),
        goal_distance=distance,
        goal_angle=angle,
        v=state.v,
        omega=state.omega,
        robot_id=robot_id,
        expected_footprint_version=expected_version,
        scan_age_s=min(max(float(scan_age_s), 0.0), MAX_SCAN_AGE_S),
    )


def twist(twist_type, vector3_type, v: float, omega: float):
    """A geometry_msgs/Twist commanding (v, omega): x ahead, rotation about z."""
    return twist_type(
        linear=vector3_type(x=float(v), y=0.0, z=0.0),
        angular=vector3_type(x=0.0, y=0.0, z=float(omega)),
    )


@dataclass(frozen=True)
class Timeouts:
    """How old (s) the latest scan and odometry may be before the robot is stopped."""

    scan_s: float = 0.5
    odom_s: float = 0.5


def stale(now: float, scan_at: float | None, odom_at: float | None, timeouts: Timeouts) -> str | None:
    """Why the robot must not move now, if its inputs are missing or too old: a message, else
    None. Times are when the messages arrived, on the node's clock (s)."""
    if scan_at is None:
        return "no scan yet"
    if odom_at is None:
        return "no odometry yet"
    if now - scan_at > timeouts.scan_s:
        return f"scan is {now - scan_at:.2f} s old (timeout {timeouts.scan_s} s)"
    if now - odom_at > timeouts.odom_s:
        return f"odometry is {now - odom_at:.2f} s old (timeout {timeouts.odom_s} s)"
    return None
