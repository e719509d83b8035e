"""`dvnav replay` over ROS 2 bags (MCAP, CDR) written here with `rosbags`: a robot driving
down a corridor towards a goal."""

import csv
import math
import subprocess

import pytest
from rosbags.rosbag2 import StoragePlugin, Writer

from conftest import REPO, TYPES, corridor_scan, odometry


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
