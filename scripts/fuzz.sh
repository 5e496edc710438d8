#!/usr/bin/env bash
# Builds the libFuzzer harnesses (fuzz/, clang, ASan + UBSan) and runs each for SECONDS
# (default 60) on its corpus. Exits non-zero on any finding (crash, exception other than
# omnicml::Error, sanitizer report, timeout > 10 s per input, RSS > 2 GB); the input
# that triggered it is saved as build-fuzz/findings/<harness>-crash-... and the log is
# build-fuzz/logs/<harness>.log.
#   scripts/fuzz.sh [SECONDS]
# Environment: OMNICML_FUZZ_BUILD_DIR (default build-fuzz), OMNICML_JOBS (default 2),
#   OMNICML_FUZZERS (space-separated subset, default all).
# The committed corpora (fuzz/corpus/<harness>/) are only read; inputs the fuzzer finds
# go to <build>/corpus/<harness>/. Reproduce a finding with
#   build-fuzz/fuzz/fuzz_<harness> FILE
set -euo pipefail
cd "$(dirname "$0")/.."
seconds="${1:-60}"
build_dir="${OMNICML_FUZZ_BUILD_DIR:-build-fuzz}"
jobs="${OMNICML_JOBS:-2}"
all_fuzzers="frames_csv session_yaml engine_file engine_config world places antworld_csv image"
fuzzers="${OMNICML_FUZZERS:-$all_fuzzers}"

# Dependencies: the library's Debian packages, clang and its sanitizer/libFuzzer runtime.
packages=(build-essential cmake ninja-build pkg-config libeigen3-dev libopencv-dev libfftw3-dev
  libceres-dev libhnswlib-dev libyaml-cpp-dev nlohmann-json3-dev clang libclang-rt-dev)
# shellcheck source=lib/packages.sh
source scripts/lib/packages.sh
install_missing fuzz "${packages[@]}"

launcher=()
if command -v ccache >/dev/null 2>&1; then launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache); fi
t0=$(date +%s)
cmake -S . -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_COMPILER=clang++ \
  "${launcher[@]}" -DOMNICML_FUZZ=ON "-DOMNICML_SANITIZE=address;undefined" \
  -DOMNICML_BUILD_TESTS=OFF -DOMNICML_BUILD_APPS=OFF -DOMNICML_BUILD_BENCHMARKS=OFF \
  -DOMNICML_BUILD_PYTHON=OFF >/dev/null
cmake --build "$build_dir" --target fuzzers -j "$jobs"
echo "fuzz: build took $(($(date +%s) - t0)) s"

export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1:allocator_may_return_null=1}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-halt_on_error=1:abort_on_error=1:print_stacktrace=1}"
mkdir -p "$build_dir/findings" "$build_dir/logs"
failed=()
summary=()
for name in $fuzzers; do
  bin="$build_dir/fuzz/fuzz_$name"
  seeds="fuzz/corpus/$name"
  work="$build_dir/corpus/$name"
  log="$build_dir/logs/$name.log"
  mkdir -p "$work"
  case "$name" in
    engine_file|image) max_len=65536 ;;
    *) max_len=16384 ;;
  esac
  rc=0
  "$bin" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -malloc_limit_mb=2048 \
    -max_len="$max_len" -print_final_stats=1 -artifact_prefix="$build_dir/findings/$name-" \
    "$work" "$seeds" >"$log" 2>&1 || rc=$?
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  line=$(printf '%-14s %10s execs in %ss' "$name" "${execs:-?}" "$seconds")
  if [ "$rc" != 0 ]; then
    failed+=("$name")
    line="$line  FINDING (exit $rc): see $log"
    grep -E "ERROR:|runtime error|terminate called|what\(\)|==[0-9]+==|deadly|Test unit written" "$log" | head -8 >&2 || true
  fi
  summary+=("$line")
  echo "fuzz: $line"
done
echo "fuzz: summary"
printf '  %s\n' "${summary[@]}"
if ((${#failed[@]})); then
  echo "fuzz: findings in: ${failed[*]}" >&2
  exit 1
fi
echo "fuzz: no findings"
