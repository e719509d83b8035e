"""Fixtures for the bridge's tests: ROS 2 message classes from `rosbags` (the real message
definitions, CDR serialization), the dvnav binary, a running `dvnav serve`."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[2]
sys.path.insert(0, str(HERE.parent))

TYPES = get_typestore(Stores.ROS2_HUMBLE)
T = TYPES.types


def header(t: float, frame: str):
    sec = int(math.floor(t))
    return T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9))),
        frame_id=frame,
    )


def laser_scan(t: float, ranges, angle_min: float, angle_increment: float, range_max=30.0):
    ranges = np.asarray(ranges, dtype=np.float32)
    return T["sensor_msgs/msg/LaserScan"](
        header=header(t, "laser"),
        angle_min=angle_min,
        angle_max=angle_min + angle_increment * (len(ranges) - 1),
        angle_increment=angle_increment,
        time_increment=0.0,
        scan_time=0.1,
        range_min=0.023,
        range_max=range_max,
        ranges=ranges,
        intensities=np.zeros(0, dtype=np.float32),
    )


def quaternion(yaw: float):
    return T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))


def vector3(x=0.0, y=0.0, z=0.0):
    return T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)


def odometry(t: float, x: float, y: float, yaw: float, v: float = 0.0, omega: float = 0.0):
    pose = T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0), orientation=quaternion(yaw)
    )
    twist = T["geometry_msgs/msg/Twist"](linear=vector3(v), angular=vector3(z=omega))
    cov = np.zeros(36, dtype=np.float64)
    return T["nav_msgs/msg/Odometry"](
        header=header(t, "odom"),
        child_frame_id="base_link",
        pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=cov),
    )


def goal_pose(x: float, y: float):
    pose = T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0), orientation=quaternion(0.0)
    )
    return T["geometry_msgs/msg/PoseStamped"](header=header(0.0, "odom"), pose=pose)


def through_cdr(msg):
    """The message as a subscriber gets it: serialized to CDR and back."""
    raw = TYPES.serialize_cdr(msg, msg.__msgtype__)
    return TYPES.deserialize_cdr(raw, msg.__msgtype__)


def corridor_scan(t: float, y: float, yaw: float, n: int = 1081, fov_deg: float = 270.0):
    """What a LiDAR at height y (m) heading yaw (rad) sees in a corridor with walls at y = ±1 m:
    +inf (no return) where a beam runs along it beyond 30 m."""
    inc = math.radians(fov_deg) / (n - 1)
    amin = -math.radians(fov_deg) / 2
    ranges = []
    for j in range(n):
        a = yaw + amin + j * inc
        s = math.sin(a)
        if s > 1e-9:
            r = (1.0 - y) / s
        elif s < -1e-9:
            r = (-1.0 - y) / s
        else:
            r = math.inf
        ranges.append(r if r <= 30.0 else math.inf)
    return laser_scan(t, ranges, amin, inc)


@pytest.fixture(scope="session")
def dvnav() -> Path:
    exe = Path(os.environ.get("DVNAV_BIN", REPO / "target/debug/dvnav"))
    if not exe.exists():
        pytest.fail(f"{exe} does not exist: build dvnav first (`cargo build`) or set DVNAV_BIN")
    return exe


class Server:
    def __init__(self, dvnav: Path, tmp: Path, footprint: str, *extra: str):
        self.addr_file = tmp / "addr"
        self.log = tmp / "serve.log"
        self.proc = subprocess.Popen(
            [str(dvnav), "serve", "--listen", "127.0.0.1:0", "--addr-file", str(self.addr_file),
             "--checkpoint", str(REPO / "models/meta-r0.2"), "--footprint", str(REPO / footprint),
             *extra],
            stdout=subprocess.DEVNULL,
            stderr=open(self.log, "w"),
            env={k: v for k, v in os.environ.items() if k != "DVNAV_TOKEN"},
        )
        deadline = time.monotonic() + 60
        while not self.addr_file.exists():
            if self.proc.poll() is not None:
                raise RuntimeError(f"dvnav serve exited: {self.log.read_text()}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"dvnav serve wrote no address: {self.log.read_text()}")
            time.sleep(0.02)
        self.addr = self.addr_file.read_text().strip()

    def stop(self):
        if self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(timeout=30)


@pytest.fixture
def server(dvnav, tmp_path):
    s = Server(dvnav, tmp_path, "footprints/small-0.15.toml")
    yield s
    s.stop()
