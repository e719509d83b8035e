"""The controller protocol's Python classes, generated from proto/ by `deploy/ros2/gen_proto.sh`
into `_proto/` beside this file (not committed: they are generated from the one source)."""

import os
import sys

_HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "_proto")
if not os.path.isdir(os.path.join(_HERE, "dvnav")):
    raise ImportError(
        f"{_HERE} has no generated protocol classes; run deploy/ros2/gen_proto.sh "
        "(needs grpcio-tools) first"
    )
if _HERE not in sys.path:
    sys.path.insert(0, _HERE)

from dvnav.controller.v1 import controller_pb2 as pb2  # noqa: E402
from dvnav.controller.v1 import controller_pb2_grpc as pb2_grpc  # noqa: E402

__all__ = ["pb2", "pb2_grpc"]
