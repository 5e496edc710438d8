#!/usr/bin/env bash
# Set-up (dependencies + Release build), then the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
# Every C++ file tracked by git matches .clang-format (Debian's clang-format); fails on a diff.
scripts/check_format.sh
build_dir="${OMNICML_BUILD_DIR:-build}"
cd "$build_dir"
ctest --output-on-failure -j "${OMNICML_JOBS:-$(nproc)}" "$@"
cd - >/dev/null

# Bounded fuzzing (fuzz/README.md): every libFuzzer harness for
# OMNICML_FUZZ_SECONDS (default 10; 0 skips) after a clang ASan+UBSan build in build-fuzz/;
# scripts/fuzz.sh installs Debian's clang and libclang-rt-14-dev when missing (measured: a
# cold clang build of the harnesses 276 s, the eight 10-s runs about 90 s). Any finding fails.
fuzz_seconds="${OMNICML_FUZZ_SECONDS:-10}"
if [ "$fuzz_seconds" != 0 ]; then
  scripts/fuzz.sh "$fuzz_seconds"
fi
