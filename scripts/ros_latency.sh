#!/usr/bin/env bash
# Latency and dropped frames of omnicml_node (docs/results.md "omnicml_node"): simulates a
# home_store day with a 720x150 panorama and with a 1280x1024 raw ring camera, exports each
# to a bag, and plays it with omnicml_ros_play at each rate (images restamped at publish,
# so latency = publish of the image -> publish of its pose) to omnicml_node (default
# queue of one frame; the new map's options per frame as configured, so that no frames are
# held at the start to measure the frame step) under a private rosmaster on a free
# loopback port. Prints one line
# per camera and rate: frames received, processed, dropped, latency p50/p99 (ms) and the
# engine's own time per frame p50 (ms).
#   scripts/ros_latency.sh [FRAMES] [RATES...]      defaults: 300 frames, 10 30 60 Hz
# Environment: OMNICML_BUILD_DIR (default build); OMNICML_ROS_COMPRESSED=1 sends the images
# as sensor_msgs/CompressedImage (PNG) instead of raw Image messages.
set -euo pipefail
cd "$(dirname "$0")/.."
build="${OMNICML_BUILD_DIR:-build}"
frames="${1:-300}"
shift || true
rates=("$@")
((${#rates[@]})) || rates=(10 30 60)
for p in "$build/omnicml" "$build/omnicml_node" "$build/omnicml_ros_play"; do
  [ -x "$p" ] || { echo "ros_latency: $p not built (ROS 1 found at configure time?)" >&2; exit 2; }
done
command -v rosmaster >/dev/null || { echo "ros_latency: rosmaster not installed" >&2; exit 2; }

work="$(mktemp -d)"
pids=()
cleanup() {
  for pid in "${pids[@]}"; do kill -- "-$pid" 2>/dev/null || true; done
  rm -rf "$work"
}
trap cleanup EXIT

port="$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')"
export ROS_MASTER_URI="http://127.0.0.1:$port" ROS_IP=127.0.0.1 ROS_HOME="$work/ros_home" ROS_LOG_DIR="$work/ros_log"
unset ROS_HOSTNAME
setsid rosmaster --core -p "$port" >"$work/master.txt" 2>&1 &
pids+=($!)

# The two cameras: home_store with a 720x150 panorama, and with a 1280x1024 ring (radii
# scaled to the larger image) unwrapped to a 720x150 panorama.
sed -e 's/panorama_height_px: 120/panorama_height_px: 150/' datasets/worlds/home_store.yaml >"$work/pano.yaml"
sed -e 's/panorama_height_px: 120/panorama_height_px: 150/' -e 's/ring_width_px: 640/ring_width_px: 1280/' \
  -e 's/ring_height_px: 480/ring_height_px: 1024/' -e 's/inner_radius_px: 40/inner_radius_px: 100/' \
  -e 's/outer_radius_px: 220/outer_radius_px: 480/' datasets/worlds/home_store.yaml >"$work/ring.yaml"
"$build/omnicml" simulate --world "$work/pano.yaml" --days 1 --frames-per-day "$frames" --panorama \
  --out "$work/pano" >/dev/null
"$build/omnicml" simulate --world "$work/ring.yaml" --days 1 --frames-per-day "$frames" --out "$work/ring" >/dev/null
compressed=()
node_compressed=false
if [ "${OMNICML_ROS_COMPRESSED:-0}" = 1 ]; then compressed=(--compressed); node_compressed=true; fi
for cam in pano ring; do
  "$build/omnicml" export rosbag "$work/$cam" --out "$work/$cam.bag" "${compressed[@]}" >/dev/null
done

for cam in pano ring; do
  for rate in "${rates[@]}"; do
    csv="$work/latency_${cam}_$rate.csv"
    setsid "$build/omnicml_node" __name:=omnicml_node _latency_csv:="$csv" _compressed:="$node_compressed" \
      _frame_step_frames:=0 \
      >"$work/node.txt" 2>&1 &
    node=$!
    pids+=("$node")
    "$build/omnicml_ros_play" "$work/$cam.bag" --rate "$rate" --timeout 30 >"$work/play.txt"
    kill -INT "$node"
    wait "$node" || true
    python3 - "$csv" "$cam" "$rate" <<'EOF'
import sys
rows, received, processed, dropped = [], 0, 0, 0
for line in open(sys.argv[1]):
    if line.startswith("stamp_s"): continue
    if line.startswith("#"):
        f = line.split(); received, processed, dropped = int(f[2]), int(f[4]), int(f[6]); continue
    rows.append([float(x) for x in line.split(",")])
def pct(v, q):
    v = sorted(v); return v[min(len(v) - 1, int(q * (len(v) - 1) + 0.5))] if v else float("nan")
lat = [r[1] for r in rows]; eng = [r[2] for r in rows]
name = {"pano": "720x150 panorama", "ring": "1280x1024 ring"}[sys.argv[2]]
print(f"{name:18s} {sys.argv[3]:>3s} Hz: received {received}, processed {processed}, dropped {dropped}; "
      f"latency p50 {pct(lat, .5):.1f} ms, p99 {pct(lat, .99):.1f} ms; engine p50 {pct(eng, .5):.1f} ms")
EOF
  done
done
