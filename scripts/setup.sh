#!/usr/bin/env bash
# Installs every dependency from Debian packages (idempotent, non-interactive), then
# configures and builds a Release build in build/.
#   scripts/setup.sh            # install + build everything (library, apps, tests, benchmarks)
# Environment: OMNICML_BUILD_DIR (default build), OMNICML_JOBS (default: number of cores).
set -euo pipefail
cd "$(dirname "$0")/.."

packages=(build-essential cmake ninja-build pkg-config libeigen3-dev libopencv-dev libfftw3-dev
  libceres-dev libhnswlib-dev libgtest-dev libgmock-dev libbenchmark-dev libcli11-dev libyaml-cpp-dev
  nlohmann-json3-dev pybind11-dev python3-dev python3-numpy snakemake libjemalloc-dev
  # ROS 1 (Debian's): rosbag import/export, omnicml_node and its test's master (rosmaster).
  libroscpp-dev librosbag-storage-dev libstd-msgs-dev libsensor-msgs-dev libnav-msgs-dev
  libgeometry-msgs-dev libvisualization-msgs-dev libtf2-msgs-dev libstd-srvs-dev python3-rosmaster
  # The replay's browser test: headless Chromium driven over the DevTools protocol.
  chromium python3-websocket
  # SHA-256 of the outputs a run directory records; libpng's messages in the one-line error.
  libssl-dev libpng-dev
  # Video frames of logs and `import video`: OpenCV's FFmpeg backend (FFV1, MJPG, H.264 ...).
  libopencv-videoio-dev)
# shellcheck source=lib/packages.sh
source scripts/lib/packages.sh
install_missing setup "${packages[@]}"

build_dir="${OMNICML_BUILD_DIR:-build}"
jobs="${OMNICML_JOBS:-$(nproc)}"
launcher=()
if command -v ccache >/dev/null 2>&1; then launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache); fi
cmake -S . -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=Release "${launcher[@]}" >/dev/null
cmake --build "$build_dir" -j "$jobs"
echo "setup: built $(pwd)/$build_dir"
