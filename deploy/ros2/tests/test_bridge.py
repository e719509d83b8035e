"""The bridge's control cycle against a real `dvnav serve`, fed real ROS 2 messages."""

import time

import grpc
import numpy as np
import pytest

from conftest import REPO, T, corridor_scan, goal_pose, header, odometry, quaternion, through_cdr
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


class _Recorder:
    """A controller stub that keeps every ActRequest and answers a plain command."""

    def __init__(self, pb2):
        self.pb2, self.sent = pb2, []

    def Act(self, request, metadata=None, timeout=None):
        self.sent.append(request)
        return self.pb2.ActReply(v=0.1, omega=0.0)


def test_each_act_says_how_long_the_scan_waited():
    from dvnav_bridge.proto import pb2

    for compensate, want in [(True, 0.15), (False, 0.0)]:
        b = BridgeCore(grpc.insecure_channel("127.0.0.1:9"), compensate_latency=compensate)
        b.stub = _Recorder(pb2)
        b.on_goal(through_cdr(goal_pose(3.0, 0.2)))
        b.on_scan(through_cdr(corridor_scan(0.0, y=0.0, yaw=0.0)), now=10.0)
        b.on_odom(through_cdr(odometry(10.0, 0.0, 0.0, 0.0)), now=10.0)
        c = b.step(10.15)
        assert c.stop is None and c.v == pytest.approx(0.1), c
        assert b.stub.sent[-1].scan_age_s == pytest.approx(want)


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


def path(points, frame="odom"):
    """A nav_msgs/Path through `points` (the robot's planner's)."""
    poses = [
        T["geometry_msgs/msg/PoseStamped"](
            header=header(0.0, frame),
            pose=T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0), orientation=quaternion(0.0)
            ),
        )
        for x, y in points
    ]
    return T["nav_msgs/msg/Path"](header=header(0.0, frame), poses=poses)


def test_follows_a_plan_by_subgoals_and_arrives_at_its_end(server):
    b = core(server)
    info = b.connect()
    b.on_plan(through_cdr(path([(0.0, 0.0), (6.0, 0.0), (6.0, 6.0)])))
    assert b.route and b.goal == (6.0, 6.0)
    b.on_scan(through_cdr(corridor_scan(0.0, y=0.0, yaw=0.0)), now=0.0)
    b.on_odom(through_cdr(odometry(0.0, 0.5, 0.0, 0.0)), now=0.0)
    c = b.step(0.1)
    # The lookahead point along the path, the meta agent's L times this robot's mu (2.5).
    look = info.lookahead_m * info.mu
    assert c.stop is None and c.subgoal == pytest.approx((0.5 + look, 0.0)), (c, look)
    assert not c.replan_wanted
    # Far off the path: the controller asks for a new plan.
    b.on_odom(through_cdr(odometry(0.2, 0.5, -3.5, 0.0)), now=0.2)
    b.on_scan(through_cdr(corridor_scan(0.2, y=0.0, yaw=0.0)), now=0.2)
    assert b.step(0.25).replan_wanted
    # At the plan's end: arrived, and the route is dropped.
    b.on_plan(through_cdr(path([(0.0, 0.0), (6.0, 0.0), (6.0, 6.0)])))
    b.on_odom(through_cdr(odometry(0.3, 6.0, 5.8, 1.5)), now=0.3)
    b.on_scan(through_cdr(corridor_scan(0.3, y=0.0, yaw=0.0)), now=0.3)
    c = b.step(0.35)
    assert c.arrived and not b.route, c
    # An empty plan clears; a plain goal then drives mapless again.
    b.on_plan(through_cdr(path([(0.0, 0.0), (3.0, 0.0)])))
    b.on_plan(through_cdr(path([])))
    assert not b.route and b.goal is None


def door_grid():
    """A 10 x 6 m OccupancyGrid (0.1 m cells) walled round, split at x = 5 m by a wall with a
    2 m door at the top (the bridge's robot has a 0.5 m radius); row 0 is the bottom, as
    map_server publishes it."""
    w, h = 100, 60
    data = []
    for row in range(h):
        y = row * 0.1 + 0.05
        for col in range(w):
            border = row < 2 or row >= h - 2 or col < 2 or col >= w - 2
            wall = 49 <= col <= 51 and not (3.6 <= y < 5.6)
            data.append(100 if border or wall else 0)
    origin = T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0), orientation=quaternion(0.0)
    )
    info = T["nav_msgs/msg/MapMetaData"](
        map_load_time=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0),
        resolution=0.1, width=w, height=h, origin=origin,
    )
    return T["nav_msgs/msg/OccupancyGrid"](header=header(0.0, "map"), info=info, data=np.array(data, dtype=np.int8))


def test_with_a_map_the_server_plans_each_goal(server):
    b = core(server)
    b.connect()
    reply = b.on_map(through_cdr(door_grid()))
    assert (reply.width, reply.height) == (100, 60) and b.has_map
    b.on_scan(through_cdr(corridor_scan(0.0, y=0.0, yaw=0.0)), now=0.0)
    b.on_odom(through_cdr(odometry(0.0, 2.0, 2.0, 0.0)), now=0.0)
    # The goal behind the wall: the server's path goes up through the door.
    b.on_goal(through_cdr(goal_pose(8.0, 2.0)))
    assert b.route
    c = b.step(0.1)
    assert c.stop is None and c.subgoal is not None and c.subgoal[1] > 2.0, c
    assert c.remaining_m > 6.0 and c.replans == 0 and not c.blocked, c
    # Held where it is (each Act a control period on), the robot stalls: the server replans
    # on its planner thread, round the scan's returns, and a later cycle reports it.
    for _ in range(400):
        c = b.step(0.1)
        if c.replans:
            break
        time.sleep(0.005)
    assert c.replans == 1 and not c.replanning and c.stop is None, c
    # A goal inside the wall is refused by the server, naming it.
    with pytest.raises(grpc.RpcError) as e:
        b.on_goal(through_cdr(goal_pose(5.0, 2.0)))
    assert e.value.code() == grpc.StatusCode.INVALID_ARGUMENT and "`goal`" in e.value.details()
