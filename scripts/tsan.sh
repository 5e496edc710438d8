#!/usr/bin/env bash
# ThreadSanitizer run (clang): builds engine_test and the omnicml CLI with
# -DOMNICML_SANITIZE=thread in build-tsan/, then runs the engine's 1-vs-2-thread tests and
# `omnicml compare --jobs 3 --threads 2` on a short home_store run. Fails on any report.
#   scripts/tsan.sh
# Environment: OMNICML_TSAN_BUILD_DIR (default build-tsan), OMNICML_JOBS (default 2),
#   OMNICML_TSAN_FRAMES (frames per day of the compare run, default 80),
#   OMNICML_TSAN_SUPPRESSIONS (default scripts/tsan.supp: hnswlib's lock order only).
# gcc 12's TSan runtime dies at start-up on some kernels; clang 14's runs here. If the
# runtime refuses the memory layout ("unexpected memory mapping"), the runs are retried
# under `setarch -R` (no address-space randomisation).
set -euo pipefail
cd "$(dirname "$0")/.."
build_dir="${OMNICML_TSAN_BUILD_DIR:-build-tsan}"
jobs="${OMNICML_JOBS:-2}"
frames="${OMNICML_TSAN_FRAMES:-80}"

packages=(clang libclang-rt-dev)
# shellcheck source=lib/packages.sh
source scripts/lib/packages.sh
install_missing tsan "${packages[@]}"

launcher=()
if command -v ccache >/dev/null 2>&1; then launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache); fi
t0=$(date +%s)
cmake -S . -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_COMPILER=clang++ \
  "${launcher[@]}" -DOMNICML_SANITIZE=thread -DOMNICML_BUILD_BENCHMARKS=OFF \
  -DOMNICML_BUILD_PYTHON=OFF >/dev/null
cmake --build "$build_dir" --target engine_test omnicml_cli -j "$jobs"
echo "tsan: build took $(($(date +%s) - t0)) s"

suppressions="${OMNICML_TSAN_SUPPRESSIONS:-$PWD/scripts/tsan.supp}"
export TSAN_OPTIONS="${TSAN_OPTIONS:-halt_on_error=1:second_deadlock_stack=1:exitcode=66}:suppressions=$suppressions"
# Runs "$@", again under setarch -R when the TSan runtime rejects the address layout.
run() {
  local log="$build_dir/tsan_$1.log"
  shift
  local rc=0
  "$@" >"$log" 2>&1 || rc=$?
  if [ "$rc" != 0 ] && grep -q "unexpected memory mapping\|FATAL: ThreadSanitizer" "$log"; then
    echo "tsan: runtime refused the memory layout; retrying under setarch -R" >&2
    rc=0
    setarch "$(uname -m)" -R "$@" >"$log" 2>&1 || rc=$?
  fi
  if [ "$rc" != 0 ]; then
    grep -A30 "WARNING: ThreadSanitizer\|FATAL" "$log" | head -60 >&2 || tail -20 "$log" >&2
    echo "tsan: FAILED (exit $rc): $log" >&2
    exit 1
  fi
  echo "tsan: ok: $log"
}

run engine_threads "$build_dir/tests/engine/engine_test" \
  --gtest_filter='CmlEngine.BitIdenticalAcrossThreadCounts:TrajectoryReconstruction.Deterministic:MapUpdater*'
rm -rf "$build_dir/tsan_compare"
run compare "$build_dir/omnicml" compare --world home_store --days 2 --frames-per-day "$frames" \
  --seed 1 --jobs 3 --threads 2 --out "$build_dir/tsan_compare"
echo "tsan: no reports"
