"""The bridge's control cycle against a real `dvnav serve`, fed real ROS 2 messages."""

import grpc
import pytest

from conftest import REPO, corridor_scan, goal_pose, odometry, through_cdr
from dvnav_bridge.bridge import BridgeCore


def core(server, **kw):
    """A bridge to `server`. Its calls get 2 s, not the node's 0.2 s: these tests are about what
    the bridge does with the answers, and a loaded CI machine can stall a process for longer
    than a control cycle (CI once saw DEADLINE_EXCEEDED on the first command)."""
    fp = (REPO / "footprints/circle-0.5.toml").read_text()
    kw.setdefault("call_timeout_s", 2.0)
    return BridgeCore(grpc.insecure_channel(server.addr), robot_id="tb2", footprint_toml=fp, **kw)


def test_drives_stops_when_stale_and_on_arrival(server):
    b = core(server)
    info = b.connect()
    assert info.mu == pytest.approx(2.5) and info.goal_tolerance == pytest.approx(0.5)
    assert b.footprint_version == info.footprint_version > 1
    assert b.step(0.0).stop == "no goal"
    b.on_goal(through_cdr(goal_pose(3.0, 0.2)))
    assert b.step(0.0).stop == "no scan yet"
    b.on_scan(through_cdr(corridor_scan(0.0, y=0.0, yaw=0.0)), now=0.0)
    b.on_odom(through_cdr(odometry(0.0, 0.0, 0.0, 0.0)), now=0.0)
    c = b.step(0.1)
    assert c.stop is None and c.v > 0.05, c
    # A scan 0.6 s old: stopped, without a call.
    c = b.step(0.6)
    assert (c.v, c.omega) == (0.0, 0.0) and c.stop.startswith("scan is"), c
    # Within 0.5 m of the goal (0.2 m scaled by mu = 2.5): arrived, stopped, goal dropped.
    b.on_scan(through_cdr(corridor_scan(1.0, y=0.2, yaw=0.0)), now=1.0)
    b.on_odom(through_cdr(odometry(1.0, 2.6, 0.2, 0.0, v=0.3)), now=1.0)
    c = b.step(1.05)
    assert (c.v, c.omega, c.arrived, c.stop) == (0.0, 0.0, True, "arrived")
    assert b.step(1.1).stop == "no goal"


def test_server_errors_stop_the_robot(server):
    b = core(server)
    b.connect()
    b.on_goal(through_cdr(goal_pose(3.0, 0.0)))
    b.on_scan(through_cdr(corridor_scan(0.0, y=0.0, yaw=0.0)), now=0.0)
    b.on_odom(through_cdr(odometry(0.0, 0.0, 0.0, 0.0)), now=0.0)
    assert b.step(0.0).stop is None
    # A scan the server refuses (a span of more than a turn): INVALID_ARGUMENT, stopped.
    bad = corridor_scan(0.0, y=0.0, yaw=0.0)
    bad.angle_increment = 0.1
    b.on_scan(bad, now=0.0)
    c = b.step(0.0)
    assert (c.v, c.omega) == (0.0, 0.0) and c.stop.startswith("server error: INVALID_ARGUMENT"), c
    b.on_scan(through_cdr(corridor_scan(0.0, y=0.0, yaw=0.0)), now=0.0)
    server.stop()
    c = b.step(0.0)
    assert (c.v, c.omega) == (0.0, 0.0) and c.stop.startswith("server error: UNAVAILABLE"), c
