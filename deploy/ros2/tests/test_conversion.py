"""The bridge's message conversion with real ROS 2 message classes and CDR (rosbags)."""

import math

import pytest

from conftest import T, corridor_scan, goal_pose, laser_scan, odometry, through_cdr
from dvnav_bridge import conversion
from dvnav_bridge.proto import pb2


def test_a_laser_scan_goes_over_as_ros_describes_it_inf_and_nan_included():
    ranges = [1.5, math.inf, -math.inf, math.nan, 0.01, 40.0]
    msg = through_cdr(laser_scan(12.25, ranges, angle_min=1.0, angle_increment=-0.25))
    got = conversion.laser_scan(pb2, msg)
    assert (got.angle_min, got.angle_increment) == (1.0, -0.25)
    assert (got.range_min, got.range_max) == (pytest.approx(0.023), 30.0)
    assert got.ranges[:3] == [1.5, math.inf, -math.inf]
    assert math.isnan(got.ranges[3]) and len(got.ranges) == 6
    # The wire form parses back the same (what the server receives).
    again = pb2.LaserScan.FromString(got.SerializeToString())
    assert again.ranges[1] == math.inf and math.isnan(again.ranges[3])
    assert conversion.stamp_seconds(msg.header) == 12.25


def test_odometry_gives_pose_heading_and_velocity():
    msg = through_cdr(odometry(3.0, x=1.0, y=-2.0, yaw=2.5, v=0.3, omega=-0.4))
    s = conversion.robot_state(msg)
    assert (s.x, s.y, s.v, s.omega) == (1.0, -2.0, 0.3, -0.4)
    assert s.yaw == pytest.approx(2.5, abs=1e-12)


@pytest.mark.parametrize(
    "pose, goal, want",
    [
        ((0.0, 0.0, 0.0), (2.0, 0.0), (2.0, 0.0)),
        ((1.0, 1.0, math.pi / 2), (1.0, 3.0), (2.0, 0.0)),
        ((1.0, 1.0, math.pi / 2), (0.0, 1.0), (1.0, math.pi / 2)),
        ((0.0, 0.0, 3.0), (-1.0, -0.1), (math.hypot(1, 0.1), math.atan2(-0.1, -1.0) - 3.0)),
    ],
)
def test_the_goal_in_the_odometry_frame_becomes_distance_and_bearing(pose, goal, want):
    s = conversion.RobotState(*pose, v=0.0, omega=0.0)
    d, a = conversion.goal_relative(goal, s)
    assert d == pytest.approx(want[0])
    assert math.sin(a) == pytest.approx(math.sin(want[1]), abs=1e-12)
    assert math.cos(a) == pytest.approx(math.cos(want[1]), abs=1e-12)
    assert -math.pi < a <= math.pi


def test_a_goal_pose_and_an_act_request():
    g = conversion.goal_xy(through_cdr(goal_pose(2.0, -1.0)))
    assert g == (2.0, -1.0)
    scan = through_cdr(corridor_scan(0.0, y=0.0, yaw=0.0))
    s = conversion.robot_state(through_cdr(odometry(0.0, 0.0, 0.0, 0.0, v=0.2)))
    r = conversion.act_request(pb2, scan, s, g, robot_id="tb2", expected_version=7)
    assert r.goal_distance == pytest.approx(math.sqrt(5))
    assert r.goal_angle == pytest.approx(math.atan2(-1.0, 2.0))
    assert (r.v, r.robot_id, r.expected_footprint_version) == (0.2, "tb2", 7)
    assert len(r.laser_scan.ranges) == 1081 and not r.scan
    assert r.scan_age_s == 0.0
    # How old the scan is, within the server's bounds.
    for age, sent in [(0.15, 0.15), (-0.01, 0.0), (7.0, 2.0)]:
        assert conversion.act_request(pb2, scan, s, g, scan_age_s=age).scan_age_s == sent


def test_a_twist_commands_v_and_omega_and_serializes():
    tw = conversion.twist(T["geometry_msgs/msg/Twist"], T["geometry_msgs/msg/Vector3"], 0.4, -0.7)
    back = through_cdr(tw)
    assert (back.linear.x, back.linear.y, back.angular.z, back.angular.x) == (0.4, 0.0, -0.7, 0.0)


def test_stale_inputs_stop_the_robot():
    t = conversion.Timeouts(scan_s=0.5, odom_s=0.3)
    assert conversion.stale(10.0, None, 9.9, t) == "no scan yet"
    assert conversion.stale(10.0, 9.9, None, t) == "no odometry yet"
    assert "scan is 0.60 s old" in conversion.stale(10.0, 9.4, 9.9, t)
    assert "odometry is 0.40 s old" in conversion.stale(10.0, 9.9, 9.6, t)
    assert conversion.stale(10.0, 9.6, 9.8, t) is None


def test_the_node_module_imports_without_rclpy():
    # rclpy is imported inside main(), so the module itself loads anywhere (a syntax error or a
    # broken import of the bridge would fail here).
    from dvnav_bridge import node

    assert callable(node.main)
