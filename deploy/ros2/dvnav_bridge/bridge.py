"""The bridge's control cycle without rclpy: the latest scan, odometry and goal in, one Act call,
one velocity command out, or a stop with its reason. `node.py` feeds it from ROS topics; the
tests feed it real ROS 2 message objects (from `rosbags`) against a real `dvnav serve`."""

from __future__ import annotations

from dataclasses import dataclass

import grpc

from . import conversion
from .proto import pb2, pb2_grpc


@dataclass(frozen=True)
class Cycle:
    """What one control cycle decided: the command to publish and, for a stop, why."""

    v: float
    omega: float
    stop: str | None = None
    arrived: bool = False
    # While following a route (/plan): the subgoal the agent was given (route frame) and
    # whether the controller asks for a new plan (the robot strayed or stalled).
    subgoal: tuple[float, float] | None = None
    replan_wanted: bool = False
    # On a route dvnav serve planned (/map and /goal_pose): the path left (m), its replans so
    # far, whether one is under way (the robot follows the old path meanwhile) and whether the
    # last found no way (the robot then heads for the goal itself).
    remaining_m: float | None = None
    replans: int = 0
    replanning: bool = False
    blocked: bool = False


STOP = (0.0, 0.0)


class BridgeCore:
    """One robot driven through a controller service. Not thread-safe: call from one thread
    (the node's executor)."""

    def __init__(
        self,
        channel: grpc.Channel,
        robot_id: str = "",
        footprint_toml: str | None = None,
        token: str | None = None,
        timeouts: conversion.Timeouts = conversion.Timeouts(),
        call_timeout_s: float = 0.2,
        compensate_latency: bool = True,
    ):
        self.stub = pb2_grpc.ControllerStub(channel)
        self.robot_id = robot_id
        self.footprint_toml = footprint_toml
        self.metadata = [("authorization", f"Bearer {token}")] if token else []
        self.timeouts = timeouts
        self.call_timeout_s = call_timeout_s
        # Send each Act the time the scan has waited since it arrived (up to a control period,
        # the timer and the scan being out of step), so the server carries it forward by the
        # commands it sent since (docs/results.md, "Latency compensation").
        self.compensate_latency = compensate_latency
        self.scan = None
        self.scan_at: float | None = None
        self.odom = None
        self.odom_at: float | None = None
        self.goal: tuple[float, float] | None = None
        self.footprint_version = 0
        self.info = None
        # A route from the robot's planner (nav_msgs/Path): its frame is the odometry's unless
        # poses come from on_pose (e.g. /amcl_pose in the map frame).
        self.route = False
        self.pose: tuple[float, float, float] | None = None
        # A map sent to the server (on_map): goals are then planned by the server (SetGoal).
        self.has_map = False

    def connect(self) -> "pb2.InfoReply":
        """Sets the robot's footprint (if it has a file) and reads what the server expects."""
        if self.footprint_toml is not None:
            self._set_footprint()
        self.info = self.stub.Info(
            pb2.InfoRequest(robot_id=self.robot_id),
            metadata=self.metadata,
            timeout=max(self.call_timeout_s, 2.0),
        )
        if self.footprint_toml is None:
            self.footprint_version = self.info.footprint_version
        return self.info

    def _set_footprint(self) -> None:
        reply = self.stub.SetFootprint(
            pb2.SetFootprintRequest(footprint_toml=self.footprint_toml, robot_id=self.robot_id),
            metadata=self.metadata,
            timeout=max(self.call_timeout_s, 2.0),
        )
        self.footprint_version = reply.footprint_version

    def on_scan(self, msg, now: float) -> None:
        self.scan, self.scan_at = msg, now

    def on_odom(self, msg, now: float) -> None:
        self.odom, self.odom_at = msg, now

    def on_goal(self, msg) -> None:
        """A new goal: with a map (on_map), the server plans the route from the robot's pose;
        without one, driven mapless (straight for it) until a plan for it comes (on_plan)."""
        self.goal = conversion.goal_xy(msg)
        if self.has_map and self._route_pose() is not None:
            x, y, yaw = self._route_pose()
            self.stub.SetGoal(
                pb2.SetGoalRequest(
                    robot_id=self.robot_id,
                    start=pb2.Pose2D(x=x, y=y, yaw=yaw),
                    goal=pb2.Pose2D(x=self.goal[0], y=self.goal[1], yaw=0.0),
                ),
                metadata=self.metadata,
                timeout=max(self.call_timeout_s, 2.0),
            )
            self.route = True
        elif self.route:
            self._set_route([])

    def on_map(self, msg) -> "pb2.SetMapReply":
        """A nav_msgs/OccupancyGrid (`/map`): sent to the server, which plans the next goals."""
        yaml, pgm = conversion.occupancy_grid_map(msg)
        reply = self.stub.SetMap(
            pb2.SetMapRequest(map_yaml=yaml, image=pgm),
            metadata=self.metadata,
            timeout=max(self.call_timeout_s, 10.0),
        )
        self.has_map = True
        return reply

    def _route_pose(self) -> tuple[float, float, float] | None:
        """The robot's pose in the route's frame: from on_pose, else the odometry's."""
        if self.pose is not None:
            return self.pose
        if self.odom is None:
            return None
        s = conversion.robot_state(self.odom)
        return (s.x, s.y, s.yaw)

    def on_plan(self, msg) -> None:
        """A nav_msgs/Path from the robot's planner: the controller follows it from now on
        (an empty one drops the route). Its last pose becomes the goal."""
        points = conversion.path_points(msg)
        self._set_route(points)
        self.goal = points[-1] if points else None

    def on_pose(self, msg) -> None:
        """The robot's pose in the plan's frame (geometry_msgs/PoseWithCovarianceStamped, e.g.
        /amcl_pose), when that is not the odometry frame."""
        p = msg.pose.pose
        self.pose = (float(p.position.x), float(p.position.y), conversion.yaw_of(p.orientation))

    def _set_route(self, points) -> None:
        self.stub.SetRoute(
            conversion.set_route_request(pb2, self.robot_id, points),
            metadata=self.metadata,
            timeout=max(self.call_timeout_s, 2.0),
        )
        self.route = bool(points)

    def step(self, now: float) -> Cycle:
        """One control cycle at `now` (s, the node's clock)."""
        if self.goal is None:
            return Cycle(*STOP, stop="no goal")
        why = conversion.stale(now, self.scan_at, self.odom_at, self.timeouts)
        if why is not None:
            return Cycle(*STOP, stop=why)
        state = conversion.robot_state(self.odom)
        pose = None
        if self.route:
            pose = self.pose if self.pose is not None else (state.x, state.y, state.yaw)
        age = now - self.scan_at if self.compensate_latency else 0.0
        request = conversion.act_request(
            pb2, self.scan, state, self.goal, self.robot_id, self.footprint_version, pose, age
        )
        try:
            reply = self.stub.Act(request, metadata=self.metadata, timeout=self.call_timeout_s)
        except grpc.RpcError as e:
            if e.code() == grpc.StatusCode.FAILED_PRECONDITION and self.footprint_toml is not None:
                # The server forgot this robot (idle expiry, restart): set its footprint again
                # and stop for this cycle rather than drive as another robot.
                try:
                    self._set_footprint()
                except grpc.RpcError as again:
                    return Cycle(*STOP, stop=f"server error: {again.code().name}: {again.details()}")
                return Cycle(*STOP, stop="footprint set again after the server forgot it")
            return Cycle(*STOP, stop=f"server error: {e.code().name}: {e.details()}")
        subgoal = (reply.subgoal_x, reply.subgoal_y) if reply.following_route else None
        if reply.arrived:
            self.goal = None
            if self.route:
                self._set_route([])
            return Cycle(*STOP, stop="arrived", arrived=True)
        return Cycle(
            reply.v,
            reply.omega,
            subgoal=subgoal,
            replan_wanted=reply.replan_wanted,
            remaining_m=reply.remaining_m if reply.following_route else None,
            replans=reply.replans,
            replanning=reply.replanning,
            blocked=reply.blocked,
        )
