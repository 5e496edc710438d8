#!/usr/bin/env bash
# The main job: install dependencies and build (scripts/setup.sh), then run the [G] Table 1
# experiment on a built-in simulated world: the same three days under passive, active and
# static forgetting. Prints the table (reference views at the given steps, mean and max
# position error) and the path of the HTML report with map-growth and error plots.
# By default [G]'s own setting: the institute world (offices whose lights and curtains
# change every few steps), 3 days x 3000 frames, views counted at steps 2000, 4000, 6000
# and 8000. About 1.5 minutes after the build on 2 cores (the three modes run in parallel).
#
#   scripts/demo.sh
# Environment: OMNICML_BUILD_DIR (default build), OMNICML_DEMO_OUT (default runs/demo),
# OMNICML_DEMO_WORLD (default institute), OMNICML_DEMO_FRAMES (frames per day, default
# 3000), OMNICML_DEMO_STEPS (default 2000,4000,6000,8000). A shorter run on the store:
# OMNICML_DEMO_WORLD=home_store OMNICML_DEMO_FRAMES=1000 OMNICML_DEMO_STEPS=1000,2000,3000
# (about 35 s).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
build_dir="${OMNICML_BUILD_DIR:-build}"
out="${OMNICML_DEMO_OUT:-runs/demo}"
world="${OMNICML_DEMO_WORLD:-institute}"
frames="${OMNICML_DEMO_FRAMES:-3000}"
steps="${OMNICML_DEMO_STEPS:-2000,4000,6000,8000}"
echo "demo: omnicml compare on world '$world', 3 days x $frames frames (passive, active, static forgetting)"
"$build_dir/omnicml" compare --world "$world" --days 3 --frames-per-day "$frames" --seed 1 \
  --steps "$steps" --threads 2 --log-every 1000 --out "$out"
case "$out" in /*) abs="$out" ;; *) abs="$(pwd)/$out" ;; esac
echo "demo: open $abs/report.html (per-mode runs in $out/passive, $out/active, $out/static)"
