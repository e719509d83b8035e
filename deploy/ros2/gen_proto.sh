#!/usr/bin/env bash
# Generates the controller protocol's Python classes (dvnav.controller.v1) for the bridge into
# deploy/ros2/dvnav_bridge/_proto/ with grpcio-tools. Usage: deploy/ros2/gen_proto.sh [PYTHON]
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
py="${1:-python3}"
out="$here/dvnav_bridge/_proto"
rm -rf "$out"
mkdir -p "$out"
"$py" -m grpc_tools.protoc -I "$here/../../proto/proto" --python_out="$out" --grpc_python_out="$out" \
  "$here/../../proto/proto/dvnav/controller/v1/controller.proto"
for d in "$out/dvnav" "$out/dvnav/controller" "$out/dvnav/controller/v1"; do touch "$d/__init__.py"; done
