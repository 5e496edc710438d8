#!/usr/bin/env bash
# The main job: install dependencies and build (scripts/setup.sh), then run the [G] Table 1
# experiment on a built-in simulated world: the same three days under passive, active and
# static forgetting. Prints the table (reference views at the given steps, mean and max
# position error) and the path of the HTML report with map-growth and error plots.
#
#   scripts/demo.sh
# Environment: OMNICML_BUILD_DIR (default build), OMNICML_DEMO_OUT (default runs/demo),
# OMNICML_DEMO_WORLD (default institute), OMNICML_DEMO_FRAMES (frames per day, default 3000: the [G] Table 1 steps 2000..8000).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
build_dir="${OMNICML_BUILD_DIR:-build}"
out="${OMNICML_DEMO_OUT:-runs/demo}"
world="${OMNICML_DEMO_WORLD:-institute}"
frames="${OMNICML_DEMO_FRAMES:-3000}"
echo "demo: omnicml compare on world '$world', 3 days x $frames frames (passive, active, static forgetting)"
"$build_dir/omnicml" compare --world "$world" --days 3 --frames-per-day "$frames" --seed 1 \
  --steps 2000,4000,6000,8000 --threads 2 --log-every 1000 --out "$out"
echo "demo: open $(pwd)/$out/report.html (per-mode runs in $out/passive, $out/active, $out/static)"
