"""`dvnav replay` over ROS 2 bags (MCAP, CDR) written here with `rosbags`: a robot driving
down a corridor towards a goal."""

import csv
import math
import subprocess

import pytest
from rosbags.rosbag2 import StoragePlugin, Writer

from conftest import REPO, TYPES, T, corridor_scan, header, odometry, quaternion


def write_bag(path, scans=40, scan_topic="/scan", odom_type="nav_msgs/msg/Odometry"):
    """10 Hz scans and 20 Hz odometry (the first odometry 0.12 s in) of a robot driving from
    (0, 0) to (2, 0) at 0.5 m/s along a corridor 2 m wide."""
    with Writer(path, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        scan_c = w.add_connection(scan_topic, "sensor_msgs/msg/LaserScan", typestore=TYPES)
        odom_c = w.add_connection("/odom", odom_type, typestore=TYPES)
        events = []
        for k in range(scans):
            t = 0.1 * k
            x = min(0.5 * t, 2.0)
            events.append((t, scan_c, corridor_scan(t, y=0.0, yaw=0.0)))
        for k in range(3, 2 * scans):
            t = 0.05 * k - 0.03
            events.append((t, odom_c, odometry(t, min(0.5 * t, 2.0), 0.0, 0.0, v=0.5)))
        for t, c, msg in sorted(events, key=lambda e: e[0]):
            w.write(c, int(1e9 + t * 1e9), TYPES.serialize_cdr(msg, msg.__msgtype__))
    return path


def replay(dvnav, bag, *args, check=True):
    return subprocess.run(
        [str(dvnav), "replay", str(bag), "--checkpoint", str(REPO / "models/meta-r0.2"), *args],
        capture_output=True, text=True, check=check, timeout=120,
    )


def test_commands_at_each_scan_with_the_path_and_arrival(dvnav, tmp_path):
    bag = write_bag(tmp_path / "bag")
    out, fig = tmp_path / "commands.csv", tmp_path / "replay.png"
    r = replay(dvnav, bag, "--goal", "2.0,0.0", "--out", str(out), "--figure", str(fig))
    rows = list(csv.DictReader(out.open()))
    # Scans at 0.0 and 0.1 s come before the first odometry (0.12 s).
    assert len(rows) == 38 and "2 scans before the first odometry skipped" in r.stdout, r.stdout
    assert [int(x["scan"]) for x in rows] == list(range(2, 40))
    for row in rows:
        x = float(row["x"])
        # The pose is the latest odometry at or before the scan: decoded from CDR as written.
        t = float(row["time_s"])
        latest = max(0.05 * k - 0.03 for k in range(3, 80) if 0.05 * k - 0.03 <= t + 1e-9)
        assert x == pytest.approx(min(0.5 * latest, 2.0), abs=1e-9), row
        assert float(row["goal_distance"]) == pytest.approx(2.0 - x, abs=1e-9)
        assert float(row["odom_v"]) == 0.5 and int(row["filled_beams"]) == 0
        assert float(row["nearest_m"]) == pytest.approx(1.0, abs=1e-3), "the walls, 1 m away"
        arrived = row["arrived"] == "true"
        # The meta robot itself (no --footprint): tolerance 0.2 m.
        assert arrived == (2.0 - x <= 0.2), row
        if arrived:
            assert (float(row["v"]), float(row["omega"])) == (0.0, 0.0)
        else:
            assert 0.0 <= float(row["v"]) <= 0.5
    assert any(float(r["v"]) > 0.2 for r in rows), "it drives down the corridor"
    assert "arrived at scan" in r.stdout
    assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_footprint_scales_the_tolerance_and_a_narrow_sensor_reports_filled_beams(dvnav, tmp_path):
    bag = write_bag(tmp_path / "bag", scans=12)
    out = tmp_path / "c.csv"
    fp = REPO / "footprints/circle-0.5.toml"
    replay(dvnav, bag, "--goal", "0.9,0", "--footprint", str(fp), "--out", str(out))
    rows = list(csv.DictReader(out.open()))
    for row in rows:
        assert (row["arrived"] == "true") == (float(row["goal_distance"]) <= 0.5), row


def test_bad_bags_and_topics_are_clear_errors(dvnav, tmp_path):
    bag = write_bag(tmp_path / "bag", scans=5)
    r = replay(dvnav, bag, "--goal", "1,0", "--scan-topic", "/laser", check=False)
    assert r.returncode != 0
    assert "no /laser messages" in r.stderr and "/scan (sensor_msgs/msg/LaserScan" in r.stderr, r.stderr
    wrong = write_bag(tmp_path / "wrong", scans=5, scan_topic="/scan2", odom_type="nav_msgs/msg/Odometry")
    r = replay(dvnav, wrong, "--goal", "1,0", "--scan-topic", "/odom", check=False)
    assert r.returncode != 0 and "carries \"nav_msgs/msg/Odometry\"" in r.stderr, r.stderr
    r = replay(dvnav, tmp_path / "missing.mcap", "--goal", "1,0", check=False)
    assert r.returncode != 0 and "no such bag" in r.stderr, r.stderr
    r = replay(dvnav, bag, "--goal", "1;0", check=False)
    assert r.returncode != 0 and "not a goal" in r.stderr, r.stderr


def test_topics_without_the_slash_and_a_bag_without_odometry(dvnav, tmp_path):
    bag = write_bag(tmp_path / "bag", scans=12)
    out = tmp_path / "c.csv"
    # `scan` is `/scan`.
    replay(dvnav, bag, "--goal", "3,0", "--scan-topic", "scan", "--odom-topic", "odom", "--out", str(out))
    assert len(list(csv.DictReader(out.open()))) == 10
    # No odometry on the topic named: a fixed sensor at the odometry origin, every scan replayed.
    r = replay(dvnav, bag, "--goal", "3,0", "--odom-topic", "/wheel_odom", "--out", str(out))
    assert "fixed sensor" in r.stderr, r.stderr
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 12 and all(float(row["x"]) == 0.0 and float(row["odom_v"]) == 0.0 for row in rows)


def write_bag_with_plans(path, plans, frame="odom", scans=40):
    """`write_bag`'s corridor drive, plus the robot's planner's nav_msgs/Path messages: `plans`
    is a list of (log time s, [(x, y), ...])."""
    with Writer(path, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        scan_c = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=TYPES)
        odom_c = w.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=TYPES)
        plan_c = w.add_connection("/plan", "nav_msgs/msg/Path", typestore=TYPES)
        events = [(0.1 * k, scan_c, corridor_scan(0.1 * k, y=0.0, yaw=0.0)) for k in range(scans)]
        for k in range(3, 2 * scans):
            t = 0.05 * k - 0.03
            events.append((t, odom_c, odometry(t, min(0.5 * t, 2.0), 0.0, 0.0, v=0.5)))
        for t, points in plans:
            poses = [
                T["geometry_msgs/msg/PoseStamped"](
                    header=header(t, frame),
                    pose=T["geometry_msgs/msg/Pose"](
                        position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                        orientation=quaternion(0.0),
                    ),
                )
                for x, y in points
            ]
            events.append((t, plan_c, T["nav_msgs/msg/Path"](header=header(t, frame), poses=poses)))
        for t, c, msg in sorted(events, key=lambda e: e[0]):
            w.write(c, int(1e9 + t * 1e9), TYPES.serialize_cdr(msg, msg.__msgtype__))
    return path


def test_a_bag_with_the_planners_paths_is_replayed_on_a_route(dvnav, tmp_path):
    # The first path down the corridor to x = 4 m; at 2.5 s the planner shortens it to x = 3 m.
    plans = [(0.05, [(0.0, 0.0), (2.0, 0.0), (4.0, 0.0)]), (2.5, [(1.25, 0.0), (3.0, 0.0)])]
    bag = write_bag_with_plans(tmp_path / "bag", plans)
    out, fig = tmp_path / "commands.csv", tmp_path / "replay.png"
    r = replay(dvnav, bag, "--out", str(out), "--figure", str(fig))
    assert "2 paths on /plan" in r.stderr and "the goal at each path's end" in r.stderr, r.stderr
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 38, r.stdout
    for row in rows:
        x, t = float(row["x"]), float(row["time_s"])
        end = 4.0 if t < 2.5 - 1e-9 else 3.0
        start = 0.0 if t < 2.5 - 1e-9 else 1.25
        # The route's goal, the path left along it, and the meta robot's 1.5 m lookahead: the
        # subgoal lies on the path 1.5 m past the robot's projection on it (the path's start
        # while the robot is short of it), or is the goal once within that.
        assert float(row["goal_distance"]) == pytest.approx(end - x, abs=1e-9), row
        assert float(row["remaining_m"]) == pytest.approx(end - x, abs=1e-6), row
        want = min(max(x, start) + 1.5, end)
        assert float(row["subgoal_x"]) == pytest.approx(want, abs=1e-6), row
        assert float(row["subgoal_y"]) == pytest.approx(0.0, abs=1e-9), row
        assert row["arrived"] == "false"
    assert any(float(r["v"]) > 0.2 for r in rows), "it drives down the corridor"
    assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # --goal is only the fallback before the first path: the route's goal wins.
    replay(dvnav, bag, "--goal", "-5,0", "--out", str(out))
    rows = list(csv.DictReader(out.open()))
    assert float(rows[0]["goal_distance"]) == pytest.approx(4.0 - float(rows[0]["x"]), abs=1e-9)


def test_a_bag_without_paths_needs_a_goal_and_a_map_frame_path_is_flagged(dvnav, tmp_path):
    bag = write_bag(tmp_path / "bag", scans=5)
    r = replay(dvnav, bag, check=False)
    assert r.returncode != 0 and "no goal" in r.stderr and "--plan-topic" in r.stderr, r.stderr
    # Without a path on --plan-topic the rows have no subgoal, as before.
    out = tmp_path / "c.csv"
    replay(dvnav, bag, "--goal", "1,0", "--out", str(out))
    assert all(row["subgoal_x"] == "" for row in csv.DictReader(out.open()))
    # A path in the map frame is read as the odometry frame, and said so.
    mapped = write_bag_with_plans(tmp_path / "mapped", [(0.05, [(0.0, 0.0), (3.0, 0.0)])], "map", 8)
    r = replay(dvnav, mapped)
    assert "paths are in frame `map`, the odometry in `odom`" in r.stderr, r.stderr
