#!/usr/bin/env bash
# Checks that a refactoring left behaviour unchanged: runs two `omnicml` binaries on the
# same inputs and compares what they write.
#
#   scripts/check_identity.sh BASE_BIN NEW_BIN [WORK_DIR]
#   scripts/check_identity.sh --build-base REF NEW_BIN [WORK_DIR]   # builds REF first
#
# --build-base adds a git worktree of REF under /tmp/omnicml-base-<ref> and builds only its
# `omnicml` target there (OMNICML_BASE_BUILD_DIR, default <worktree>/build).
#
# Compared, per world (OMNICML_CHECK_WORLDS, default "home_store institute store_large"),
# seed 1, OMNICML_CHECK_DAYS (2) x OMNICML_CHECK_FRAMES (300) frames per day:
#   `omnicml compare` (passive, active, static): the printed table, and for every mode
#   every CSV of the run directory with its timing columns removed (time_*, *_us, *_ms,
#   *wall*, *cpu*, *rss*) and its TUM files byte for byte;
#   `omnicml run --map-out` (default options): frames.csv as above and the saved map
#   byte for byte;
#   the fuzz corpora (fuzz/corpus) through the commands that read them: exit code and
#   output, with run directories and temporary paths masked.
# Prints one line per comparison and exits 1 if any differs (diffs under WORK_DIR/diff).
set -euo pipefail
cd "$(dirname "$0")/.."

if [[ "${1:-}" == "--build-base" ]]; then
  ref="$2"
  shift 2
  tree="/tmp/omnicml-base-${ref}"
  [[ -d "$tree" ]] || git worktree add --detach "$tree" "$ref" >/dev/null
  build="${OMNICML_BASE_BUILD_DIR:-$tree/build}"
  launcher=()
  if command -v ccache >/dev/null 2>&1; then launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache); fi
  cmake -S "$tree" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=Release -DOMNICML_BUILD_TESTS=OFF \
    -DOMNICML_BUILD_BENCHMARKS=OFF -DOMNICML_BUILD_PYTHON=OFF "${launcher[@]}" >/dev/null
  cmake --build "$build" -j "${OMNICML_JOBS:-2}" --target omnicml_cli
  base_bin="$build/omnicml"
else
  base_bin="${1:?usage: check_identity.sh BASE_BIN NEW_BIN [WORK_DIR]}"
  shift
fi
new_bin="$(realpath "${1:?usage: check_identity.sh BASE_BIN NEW_BIN [WORK_DIR]}")"
base_bin="$(realpath "$base_bin")"
work="${2:-/tmp/omnicml-identity}"
worlds="${OMNICML_CHECK_WORLDS:-home_store institute store_large}"
days="${OMNICML_CHECK_DAYS:-2}"
frames="${OMNICML_CHECK_FRAMES:-300}"
rm -rf "$work"
mkdir -p "$work/base" "$work/new" "$work/diff"
failures=0

report() {  # report NAME STATUS
  printf '%-60s %s\n' "$1" "$2"
  [[ "$2" == same ]] || failures=$((failures + 1))
}

# A CSV without its timing columns.
strip_timing() {
  python3 - "$1" <<'EOF'
import csv, re, sys
timing = re.compile(r"(^time_|_us$|_ms$|wall|cpu|rss)")
with open(sys.argv[1], newline="") as f:
    rows = list(csv.reader(f))
if not rows:
    sys.exit(0)
keep = [i for i, name in enumerate(rows[0]) if not timing.search(name)]
w = csv.writer(sys.stdout, lineterminator="\n")
for r in rows:
    w.writerow([r[i] for i in keep if i < len(r)])
EOF
}

compare_files() {  # compare_files NAME A B
  if cmp -s "$2" "$3"; then report "$1" same; else
    diff <(xxd "$2" | head -200) <(xxd "$3" | head -200) >"$work/diff/${1//\//_}.diff" || true
    report "$1" DIFFERENT
  fi
}

compare_text() {  # compare_text NAME A B
  if diff "$2" "$3" >"$work/diff/${1//\//_}.diff"; then report "$1" same; else report "$1" DIFFERENT; fi
}

# Output with run-specific text masked: the work directories and timings.
mask() {
  sed -E -e "s#$work/(base|new)#WORK#g" -e 's#[0-9]+(\.[0-9]+)? ?(ms|s|us)\b#TIME#g' \
    -e 's#[0-9]+(\.[0-9]+)? frames/s#TIME#g'
}

for world in $worlds; do
  for side in base new; do
    bin="$base_bin"
    [[ "$side" == new ]] && bin="$new_bin"
    out="$work/$side/compare_$world"
    nice "$bin" compare --world "$world" --days "$days" --frames-per-day "$frames" --seed 1 \
      --steps "$frames,$((2 * frames))" --threads 1 --quiet --out "$out" >"$out.stdout" 2>&1 || true
  done
  mask <"$work/base/compare_$world.stdout" | grep -viE 'time|took' >"$work/base/compare_$world.table" || true
  mask <"$work/new/compare_$world.stdout" | grep -viE 'time|took' >"$work/new/compare_$world.table" || true
  compare_text "$world/table" "$work/base/compare_$world.table" "$work/new/compare_$world.table"
  for mode in passive active static; do
    b="$work/base/compare_$world/$mode"
    n="$work/new/compare_$world/$mode"
    [[ -d "$b" ]] || { report "$world/$mode (no run directory)" DIFFERENT; continue; }
    while IFS= read -r -d '' f; do
      rel="${f#"$b"/}"
      strip_timing "$f" >"$work/a.csv"
      strip_timing "$n/$rel" >"$work/b.csv" 2>/dev/null || : >"$work/b.csv"
      compare_text "$world/$mode/$rel" "$work/a.csv" "$work/b.csv"
    done < <(find "$b" -name '*.csv' -print0 | sort -z)
    while IFS= read -r -d '' f; do
      rel="${f#"$b"/}"
      compare_files "$world/$mode/$rel" "$f" "$n/$rel"
    done < <(find "$b" -name '*.tum' -print0 | sort -z)
  done
  for side in base new; do
    bin="$base_bin"
    [[ "$side" == new ]] && bin="$new_bin"
    out="$work/$side/run_$world"
    nice "$bin" run --world "$world" --days "$days" --frames-per-day "$frames" --seed 1 \
      --threads 1 --quiet --out "$out" --map-out "$out.map" >"$out.stdout" 2>&1 || true
  done
  strip_timing "$work/base/run_$world/frames.csv" >"$work/a.csv"
  strip_timing "$work/new/run_$world/frames.csv" >"$work/b.csv" 2>/dev/null || : >"$work/b.csv"
  compare_text "$world/run/frames.csv" "$work/a.csv" "$work/b.csv"
  compare_files "$world/run/map" "$work/base/run_$world.map" "$work/new/run_$world.map"
  mask <"$work/base/run_$world.stdout" >"$work/a.txt"
  mask <"$work/new/run_$world.stdout" >"$work/b.txt"
  compare_text "$world/run/stdout" "$work/a.txt" "$work/b.txt"
done

# The fuzz corpora through the CLI: exit code and messages.
run_both() {  # run_both NAME ARGS... (ARGS may use @OUT@ for a fresh output path)
  local name="$1"
  shift
  for side in base new; do
    local bin="$base_bin"
    [[ "$side" == new ]] && bin="$new_bin"
    local out="$work/$side/fuzz_out"
    rm -rf "$out"
    local args=("${@//@OUT@/$out}")
    set +e
    nice "$bin" "${args[@]}" >"$work/$side/fuzz.stdout" 2>"$work/$side/fuzz.stderr"
    echo "exit $?" >"$work/$side/fuzz.result"
    set -e
    cat "$work/$side/fuzz.stderr" "$work/$side/fuzz.stdout" | mask | grep -viE 'time|took' \
      >>"$work/$side/fuzz.result" || true
  done
  compare_text "fuzz/$name" "$work/base/fuzz.result" "$work/new/fuzz.result"
}

for f in fuzz/corpus/engine_config/*; do
  run_both "engine_config/$(basename "$f")" run --config "$f" --world home_store --days 1 \
    --frames-per-day 5 --quiet --out @OUT@
done
for f in fuzz/corpus/engine_file/*; do
  run_both "engine_file/$(basename "$f")" inspect "$f"
done
# The maps the base binary saved, read by both (the new one must load the old format).
for world in $worlds; do
  [[ -f "$work/base/run_$world.map" ]] && run_both "inspect $world map" inspect "$work/base/run_$world.map"
done
for f in fuzz/corpus/world/*; do
  run_both "world/$(basename "$f")" simulate --world "$f" --days 1 --frames-per-day 3 --out @OUT@
done
for f in fuzz/corpus/image/*; do
  run_both "image/$(basename "$f")" describe "$f"
done
for f in fuzz/corpus/antworld_csv/*; do
  run_both "antworld_csv/$(basename "$f")" import antworld "$f" --out @OUT@
done
for f in fuzz/corpus/session_yaml/*; do
  mkdir -p "$work/session_$(basename "$f")"
  cp "$f" "$work/session_$(basename "$f")/session.yaml"
  run_both "session_yaml/$(basename "$f")" validate "$work/session_$(basename "$f")"
done

if ((failures > 0)); then
  echo "check_identity: $failures comparison(s) differ (diffs in $work/diff)"
  exit 1
fi
echo "check_identity: all comparisons identical"
