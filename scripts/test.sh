#!/usr/bin/env bash
# Set-up (dependencies + Release build), then the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
build_dir="${OMNICML_BUILD_DIR:-build}"
cd "$build_dir"
ctest --output-on-failure -j "${OMNICML_JOBS:-$(nproc)}" "$@"
