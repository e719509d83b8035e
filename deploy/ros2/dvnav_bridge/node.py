"""The ROS 2 node: subscribes sensor_msgs/LaserScan (`scan`), nav_msgs/Odometry (`odom`) and
geometry_msgs/PoseStamped (`goal_pose`, in the odometry frame), calls `dvnav serve` at the
control period and publishes geometry_msgs/Twist on `cmd_vel`; a zero Twist on arrival, on a
stale scan or odometry, and on a server error. With a map (nav_msgs/OccupancyGrid on `map`)
the server plans each goal itself (SetMap, SetGoal). With a planner: nav_msgs/Path on `plan` is
followed by subgoals (SetRoute), the robot's pose from `odom` or, with `-p pose_topic:=amcl_pose`,
from that geometry_msgs/PoseWithCovarianceStamped (the plan's frame); the subgoal is published
on `dvnav/subgoal` (geometry_msgs/PointStamped) and a wanted replan is logged. See
deploy/ros2/README.md.

    python3 -m dvnav_bridge.node --ros-args -p server:=127.0.0.1:50061 \
        -p footprint_file:=footprints/paper-medium.toml -p robot_id:=tb2
"""

from __future__ import annotations

import os

import grpc


def main(args=None) -> None:
    # rclpy and the message packages come with ROS 2; imported here so that the conversion and
    # the control cycle import (and are tested) without them.
    import rclpy
    from geometry_msgs.msg import Point, PointStamped, PoseStamped, PoseWithCovarianceStamped, Twist, Vector3
    from nav_msgs.msg import OccupancyGrid, Odometry, Path
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import LaserScan

    from . import conversion
    from .bridge import BridgeCore

    class DvnavBridge(Node):
        def __init__(self):
            super().__init__("dvnav_bridge")
            server = self.declare_parameter("server", "127.0.0.1:50061").value
            robot_id = self.declare_parameter("robot_id", "").value
            footprint_file = self.declare_parameter("footprint_file", "").value
            ca_file = self.declare_parameter("tls_ca", "").value
            timeouts = conversion.Timeouts(
                scan_s=self.declare_parameter("scan_timeout_s", 0.5).value,
                odom_s=self.declare_parameter("odom_timeout_s", 0.5).value,
            )
            token = os.environ.get("DVNAV_TOKEN") or None
            if ca_file:
                with open(ca_file, "rb") as f:
                    channel = grpc.secure_channel(server, grpc.ssl_channel_credentials(f.read()))
            else:
                channel = grpc.insecure_channel(server)
            footprint = None
            if footprint_file:
                with open(footprint_file, encoding="utf-8") as f:
                    footprint = f.read()
            compensate = self.declare_parameter("compensate_latency", True).value
            self.core = BridgeCore(
                channel, robot_id, footprint, token, timeouts, compensate_latency=compensate
            )
            info = self.core.connect()
            period = info.control_period_s
            self.get_logger().info(
                f"dvnav serve at {server}: model {info.model} ({info.model_version}), footprint "
                f"{info.footprint!r}, mu {info.mu:.3f}, goal tolerance {info.goal_tolerance:.3f} m, "
                f"control period {period} s"
            )
            self.cmd = self.create_publisher(Twist, "cmd_vel", 10)
            self.create_subscription(LaserScan, "scan", self._scan, qos_profile_sensor_data)
            self.create_subscription(Odometry, "odom", self._odom, 20)
            self.create_subscription(PoseStamped, "goal_pose", self._goal, 10)
            self.create_subscription(Path, "plan", self._plan, 10)
            # map_server publishes the map once, transient local: a late subscriber still gets it.
            latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
            self.create_subscription(OccupancyGrid, "map", self._map, latched)
            pose_topic = self.declare_parameter("pose_topic", "").value
            if pose_topic:
                self.create_subscription(PoseWithCovarianceStamped, pose_topic, self.core.on_pose, 10)
            self.plan_frame = "odom"
            self.subgoal = self.create_publisher(PointStamped, "dvnav/subgoal", 10)
            self._Point, self._PointStamped = Point, PointStamped
            self._replan_logged = False
            self._replans_seen = 0
            self.create_timer(period, self._tick)
            self._last_stop = None
            self._Twist, self._Vector3 = Twist, Vector3

        def _now(self) -> float:
            return self.get_clock().now().nanoseconds * 1e-9

        def _scan(self, msg):
            self.core.on_scan(msg, self._now())

        def _odom(self, msg):
            self.core.on_odom(msg, self._now())

        def _goal(self, msg):
            try:
                self.core.on_goal(msg)
            except grpc.RpcError as e:
                self.core.goal = None
                self.get_logger().error(f"goal refused: {e.code().name}: {e.details()}")
                return
            self.get_logger().info(f"goal ({msg.pose.position.x:.2f}, {msg.pose.position.y:.2f})")

        def _map(self, msg):
            try:
                reply = self.core.on_map(msg)
            except grpc.RpcError as e:
                self.get_logger().error(f"map refused: {e.code().name}: {e.details()}")
                return
            self.plan_frame = msg.header.frame_id or "map"
            self.get_logger().info(
                f"map {reply.width} x {reply.height} at {reply.resolution} m sent: goals are planned by dvnav serve"
            )

        def _plan(self, msg):
            self.core.on_plan(msg)
            self.plan_frame = msg.header.frame_id or "odom"
            self._replan_logged = False
            self.get_logger().info(f"route of {len(msg.poses)} poses in frame {self.plan_frame!r}")

        def _tick(self):
            c = self.core.step(self._now())
            self.cmd.publish(conversion.twist(self._Twist, self._Vector3, c.v, c.omega))
            if c.subgoal is not None:
                m = self._PointStamped()
                m.header.frame_id = self.plan_frame
                m.header.stamp = self.get_clock().now().to_msg()
                m.point = self._Point(x=c.subgoal[0], y=c.subgoal[1], z=0.0)
                self.subgoal.publish(m)
            if c.replans > self._replans_seen:
                left = "no way left: heading for the goal itself" if c.blocked else f"{c.remaining_m:.1f} m left"
                self.get_logger().info(f"dvnav serve replanned the route ({c.replans} so far): {left}")
            self._replans_seen = c.replans
            if c.replan_wanted and not self._replan_logged:
                self.get_logger().warn("the robot strayed from the plan or stalled: replan wanted")
                self._replan_logged = True
            if c.stop != self._last_stop and c.stop is not None:
                log = self.get_logger().info if c.arrived or c.stop == "no goal" else self.get_logger().warn
                log(f"stopped: {c.stop}")
            self._last_stop = c.stop

    rclpy.init(args=args)
    node = DvnavBridge()
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.cmd.publish(conversion.twist(node._Twist, node._Vector3, 0.0, 0.0))
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
