"""A robot's side of `dvnav serve`, as an example: Info, one Act, a footprint change, Act again,
Act with a LaserScan and at the goal, and two refusals (a NaN in the scan; a call without the
token).

    pip install grpcio grpcio-tools
    python3 scripts/controller_client.py [--addr 127.0.0.1:50061] [--token-file token]
        [--tls-ca ca.pem [--tls-domain NAME]]

With --tls-ca (a server run with --tls-cert/--tls-key; `dvnav certs` writes ca.pem) the
channel is TLS and trusts that CA.

The Python stubs are generated from proto/ into a temporary directory at start, so the script
always speaks the protocol of this checkout.
"""

import argparse
import pathlib
import sys
import tempfile

import grpc
from grpc_tools import protoc

REPO = pathlib.Path(__file__).resolve().parent.parent
PROTO = "dvnav/controller/v1/controller.proto"


def stubs():
    out = tempfile.mkdtemp(prefix="dvnav-controller-")
    args = ["protoc", f"-I{REPO / 'proto/proto'}", f"--python_out={out}", f"--grpc_python_out={out}"]
    if protoc.main(args + [PROTO]) != 0:
        sys.exit(f"cannot compile {PROTO}")
    sys.path.insert(0, out)
    from dvnav.controller.v1 import controller_pb2, controller_pb2_grpc

    return controller_pb2, controller_pb2_grpc


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--addr", default="127.0.0.1:50061")
    p.add_argument("--token-file", help="the server's --token-file")
    p.add_argument("--tls-ca", help="connect over TLS, trusting this CA certificate (PEM)")
    p.add_argument("--tls-domain", help="the name to verify in the server's certificate when "
                   "--addr's host is not in it")
    p.add_argument("--cargo", default=str(REPO / "footprints/circle-with-cargo.toml"),
                   help="the footprint file sent with SetFootprint")
    a = p.parse_args()
    pb, rpc = stubs()

    if a.tls_ca:
        creds = grpc.ssl_channel_credentials(root_certificates=open(a.tls_ca, "rb").read())
        options = [("grpc.ssl_target_name_override", a.tls_domain)] if a.tls_domain else []
        channel = grpc.secure_channel(a.addr, creds, options=options)
    else:
        channel = grpc.insecure_channel(a.addr)
    ctl = rpc.ControllerStub(channel)
    token = open(a.token_file).read().strip() if a.token_file else None
    auth = [("authorization", "Bearer " + token)] if token else []

    info = ctl.Info(pb.InfoRequest(), metadata=auth)
    print(f"{info.scan_beams} beams over {info.scan_fov_deg:.0f} deg, every {info.control_period_s} s;"
          f" mu {info.mu:.2f}, {info.scaled_robot}; {info.model} {info.model_version}")

    scan = [2.5] * info.scan_beams  # the LiDAR's ranges (m), in the meta agent's beam layout
    req = pb.ActRequest(scan=scan, goal_distance=3.0, goal_angle=0.6, v=0.2, omega=0.0,
                        robot_id="cart-1")
    cmd = ctl.Act(req, metadata=auth)
    print(f"v {cmd.v:.3f} m/s, omega {cmd.omega:.3f} rad/s"
          f" (mu {cmd.mu:.2f}, footprint {cmd.footprint_version})")

    # It picks up cargo.
    toml = open(a.cargo).read()
    new = ctl.SetFootprint(pb.SetFootprintRequest(footprint_toml=toml, robot_id="cart-1"),
                           metadata=auth)
    print(f"mu {new.mu:.4f}, {new.scaled_robot}, footprint {new.footprint_version}")
    cmd = ctl.Act(req, metadata=auth)
    print(f"v {cmd.v:.3f} m/s, omega {cmd.omega:.3f} rad/s"
          f" (mu {cmd.mu:.2f}, footprint {cmd.footprint_version})")

    # The same robot with its LiDAR's own scan: a Hokuyo UTM-30LX's 1,081 readings over 270°,
    # one of them with no return (+inf); the server resamples it to the meta agent's beams.
    laser = pb.LaserScan(angle_min=-2.35619449, angle_increment=0.00436332313, range_min=0.023,
                         range_max=30.0, ranges=[2.5] * 540 + [float("inf")] + [2.5] * 540)
    cmd = ctl.Act(pb.ActRequest(laser_scan=laser, goal_distance=3.0, goal_angle=0.6, v=0.2,
                                robot_id="cart-1"), metadata=auth)
    print(f"LaserScan: v {cmd.v:.3f} m/s, omega {cmd.omega:.3f} rad/s, "
          f"{cmd.filled_beams} meta beams unseen")
    cmd = ctl.Act(pb.ActRequest(laser_scan=laser, goal_distance=0.3, robot_id="cart-1"),
                  metadata=auth)
    print(f"0.30 m from the goal: arrived {cmd.arrived} (tolerance {cmd.goal_tolerance:.3f} m), "
          f"v {cmd.v:.3f}, omega {cmd.omega:.3f}")

    scan[17] = float("nan")
    try:
        ctl.Act(pb.ActRequest(scan=scan, goal_distance=3.0), metadata=auth)
    except grpc.RpcError as e:
        print(e.code(), e.details())
    if token:
        try:
            ctl.Info(pb.InfoRequest())
        except grpc.RpcError as e:
            print(e.code(), e.details())


if __name__ == "__main__":
    main()
