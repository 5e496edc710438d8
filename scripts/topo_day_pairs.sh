#!/usr/bin/env bash
# The [UN] cross-sequence experiment (`omnicml topo`) over every ordered
# train/test pair of 3 simulated days, seeds 1-3, on home_store (285 frames a day, one
# lap, datasets/places/home_store_areas.yaml) and institute (180 frames a day,
# datasets/places/institute_rooms.yaml), with the localizer's defaults. Prints per world
# the confident-correct / confident-wrong percentages of every run, their mean and worst,
# the outcome per true place (which places are confused with which) and the share of
# frames in which each band's nearest neighbour names another place, per true place.
# About 2 minutes on 2 cores after the build (runs are sequential).
#
#   scripts/topo_day_pairs.sh [OUT_DIR] [extra `omnicml topo` flags, e.g. --config FILE]
# Environment: OMNICML_BUILD_DIR (default build), TOPO_WORLDS (default
# "home_store institute"), TOPO_SEEDS (default "1 2 3").
set -euo pipefail
cd "$(dirname "$0")/.."
build_dir="${OMNICML_BUILD_DIR:-build}"
out="${1:-runs/topo_day_pairs}"
shift || true
for world in ${TOPO_WORLDS:-home_store institute}; do
  case "$world" in
    home_store) frames=285 places=datasets/places/home_store_areas.yaml ;;
    institute) frames=180 places=datasets/places/institute_rooms.yaml ;;
    *) echo "unknown world $world" >&2; exit 2 ;;
  esac
  for seed in ${TOPO_SEEDS:-1 2 3}; do
    for train in 1 2 3; do
      for test in 1 2 3; do
        [ "$train" = "$test" ] && continue
        run="$out/${world}_s${seed}_${train}${test}"
        rm -rf "$run"
        "$build_dir/omnicml" topo --world "$world" --days 3 --frames-per-day "$frames" \
          --seed "$seed" --train-day "$train" --test-day "$test" --places "$places" \
          --out "$run" "$@" > /dev/null
      done
    done
  done
done
python3 - "$out" <<'EOF'
import collections, csv, glob, os, sys
out = sys.argv[1]
worlds = collections.defaultdict(list)
for d in sorted(glob.glob(os.path.join(out, "*_s*_*"))):
    world, seed, pair = os.path.basename(d).rsplit("_", 2)
    worlds[world].append((seed[1:], pair, list(csv.DictReader(open(os.path.join(d, "frames.csv"))))))
for world, runs in worlds.items():
    print(f"## {world}\n\n| seed | train -> test | confident correct % | confident wrong % | confused % | uncertain % |")
    print("|---|---|---|---|---|---|")
    cc_all, cw_all = [], []
    outcome = collections.Counter()
    band_wrong = collections.defaultdict(collections.Counter)
    per_place = collections.Counter()
    for seed, pair, rows in runs:
        rows = [r for r in rows if r["true_place"]]
        n = len(rows)
        cc = sum(r["state"] == "confident" and r["voted_place"] == r["true_place"] for r in rows)
        cw = sum(r["state"] == "confident" and r["voted_place"] != r["true_place"] for r in rows)
        cf = sum(r["state"] == "confused" for r in rows)
        un = n - cc - cw - cf
        cc_all.append(100 * cc / n); cw_all.append(100 * cw / n)
        print(f"| {seed} | {pair[0]} -> {pair[1]} | {100*cc/n:.1f} | {100*cw/n:.1f} | {100*cf/n:.1f} | {100*un/n:.1f} |")
        vote_keys = [k for k in rows[0] if k.startswith("vote_")]
        for r in rows:
            tp = r["true_place"]
            per_place[tp] += 1
            if r["state"] == "confident":
                outcome[(tp, "confident " + ("correct" if r["voted_place"] == tp else "wrong -> " + r["voted_place"]))] += 1
            elif r["state"] == "confused":
                voted = sorted({r[k] for k in vote_keys if r[k]})
                outcome[(tp, "confused " + "/".join(voted))] += 1
            else:
                outcome[(tp, "uncertain")] += 1
            for k in vote_keys:
                band_wrong[tp][k[5:]] += r[k] != tp
    print(f"\nconfident correct: mean {sum(cc_all)/len(cc_all):.1f} %, worst {min(cc_all):.1f} %; "
          f"confident wrong: mean {sum(cw_all)/len(cw_all):.2f} %, worst {max(cw_all):.1f} % "
          f"({len(cc_all)} runs)\n")
    print("| frames | true place | outcome |\n|---|---|---|")
    for (tp, what), k in sorted(outcome.items(), key=lambda x: (-x[1], x[0])):
        print(f"| {k} | {tp} | {what} |")
    bands = list(next(iter(band_wrong.values())).keys())
    print("\nnearest neighbour of another place, % of frames, per band:\n")
    print("| true place | frames | " + " | ".join(bands) + " |\n|---|---|" + "---|" * len(bands))
    for tp in sorted(per_place):
        print(f"| {tp} | {per_place[tp]} | " + " | ".join(f"{100*band_wrong[tp][b]/per_place[tp]:.0f}" for b in bands) + " |")
    print()
EOF
