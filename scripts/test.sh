#!/usr/bin/env bash
# Set-up (dependencies + Release build), then the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
build_dir="${OMNICML_BUILD_DIR:-build}"
cd "$build_dir"
ctest --output-on-failure -j "${OMNICML_JOBS:-$(nproc)}" "$@"
cd - >/dev/null

# Bounded fuzzing (fuzz/README.md): every libFuzzer harness for OMNICML_FUZZ_SECONDS
# (default 10; 0 skips) after a clang ASan+UBSan build in build-fuzz/. Runs only when
# Debian's clang and its libFuzzer runtime (libclang-rt-14-dev) are installed (a fresh
# machine has neither; scripts/fuzz.sh installs them): the step costs ~6 min on 2 cores
# without ccache (measured: clang ASan+UBSan build of the 10 libraries and 8 harnesses
# 276 s, then 8 x 10 s of fuzzing), ~2 min with a warm ccache.
fuzz_seconds="${OMNICML_FUZZ_SECONDS:-10}"
if [ "$fuzz_seconds" != 0 ]; then
  if command -v clang++ >/dev/null 2>&1 &&
      [ -f "$(clang++ -print-file-name=libclang_rt.fuzzer-x86_64.a)" ]; then
    scripts/fuzz.sh "$fuzz_seconds"
  else
    echo "test: fuzzing skipped: clang with libFuzzer (libclang-rt-14-dev) is not installed"
  fi
fi
