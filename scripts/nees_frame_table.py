#!/usr/bin/env python3
"""Per-run position NEES against the world and against the run's own map frame.

For each run directory SWEEP_DIR/runs/<job>/<mode> (a compare sweep) or each RUN_DIR given
with --runs, runs `omnicml evaluate RUN --align none` and `--align se2` (the best rigid 2-D
fit of the estimate onto the truth over the run: the map frame's error, which every frame
of the run shares) and prints a markdown table: mean error, position NEES median and p95,
world and aligned, and the fitted rotation and shift. Then the summary over the runs:
runs with the NEES median in [0.7, 2.8] and the p95 in [3, 12] (docs/results.md targets),
and, pooled over every frame of every run, mean(e^2) / mean(trace C_xy) (1 for an
ensemble-consistent covariance; frames.csv) with the count of runs whose median would be
in band if every covariance were scaled by that ratio (what a scale alone can do).

Frames: every frame of a run is counted; a frame without an estimate or a covariance is
reported in the frames column, not dropped silently.

With --first-frames N it also fits the rotation per day from frames.csv (the same rigid
fit, over one day's frames) and prints, over days >= 2 of every run: the mean and largest
absolute rotation, the mean and spread of rotation + the day's mean heading error (near 0
when the heading follows a rotated map), the rotation of each run's first N frames and
the map's views after them.

Usage: scripts/nees_frame_table.py OMNICML (SWEEP_DIR [--mode active] | --runs RUN_DIR...)
  [--first-day N]     (pooled ratio over days >= N, 1-based; default 1)
  [--first-frames N]  (per-day rotations, and that of each run's first N frames)
"""
import argparse
import csv
import math
import os
import re
import subprocess
import sys
import tempfile

BAND_MEDIAN = (0.7, 2.8)
BAND_P95 = (3.0, 12.0)


def evaluate(omnicml, run, align):
    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run([omnicml, "evaluate", run, "--align", align, "--out",
                              os.path.join(tmp, "e.html")], check=True, capture_output=True,
                             text=True).stdout
    res = {"rot_deg": 0.0, "shift_m": 0.0}
    m = re.search(r"alignment: se2 \(tx (\S+) m, ty (\S+) m, theta (\S+) deg\)", out)
    if m:
        res["shift_m"] = math.hypot(float(m.group(1)), float(m.group(2)))
        res["rot_deg"] = float(m.group(3))
    for line in out.splitlines():
        f = line.split()
        if f[:1] == ["all"] and len(f) > 6 and "mean_err" not in res and f[1].isdigit():
            res["frames"], res["localized"], res["mean_err"] = int(f[1]), int(f[2]), float(f[6])
        if line.startswith("position NEES"):
            g = line[len("position NEES"):].split()
            res["nees_frames"] = g[1]
            res["nees_med"], res["nees_p95"] = float(g[3]), float(g[4])
    return res


def read_frames(run):
    with open(os.path.join(run, "frames.csv")) as fh:
        return list(csv.DictReader(fh))


def pooled(frames, first_day):
    """Sum of e^2 and of trace C_xy over the frames with a NEES of days >= first_day."""
    e2 = tr = 0.0
    for r in frames:
        if int(r["session"]) + 1 < first_day or not r["nees_xy"]:
            continue
        e2 += float(r["position_error_m"]) ** 2
        tr += float(r["cov_xx_m2"]) + float(r["cov_yy_m2"])
    return e2, tr


def rigid_rotation_deg(rows):
    """Rotation (deg) of the least-squares rigid 2-D fit of the estimates onto the truth."""
    n = len(rows)
    e = [(float(r["est_x_m"]), float(r["est_y_m"])) for r in rows]
    t = [(float(r["truth_x_m"]), float(r["truth_y_m"])) for r in rows]
    me = (sum(p[0] for p in e) / n, sum(p[1] for p in e) / n)
    mt = (sum(p[0] for p in t) / n, sum(p[1] for p in t) / n)
    cross = sum((a[0] - me[0]) * (b[1] - mt[1]) - (a[1] - me[1]) * (b[0] - mt[0])
                for a, b in zip(e, t))
    dot = sum((a[0] - me[0]) * (b[0] - mt[0]) + (a[1] - me[1]) * (b[1] - mt[1])
              for a, b in zip(e, t))
    return math.degrees(math.atan2(cross, dot))


def day_rotations(frames, first_frames):
    """[(rotation, mean heading error) per day >= 2], the first frames' rotation and the
    map's views after them."""
    views = int(frames[min(first_frames, len(frames)) - 1]["views"])
    rows = [r for r in frames if r["est_x_m"] and r["truth_x_m"]]
    days = {}
    for r in rows:
        days.setdefault(int(r["session"]), []).append(r)
    out = []
    for day, rs in sorted(days.items()):
        if day == 0 or len(rs) < 2:
            continue
        head = sum(math.remainder(float(r["est_phi_rad"]) - float(r["truth_phi_rad"]),
                                  2 * math.pi) for r in rs) / len(rs)
        out.append((rigid_rotation_deg(rs), math.degrees(head)))
    return out, rigid_rotation_deg(rows[:first_frames]), views


def main(argv):
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        usage="%(prog)s OMNICML (SWEEP_DIR [--mode MODE] | --runs RUN_DIR...) "
              "[--first-day N] [--first-frames N]")
    parser.add_argument("omnicml", help="the omnicml binary")
    parser.add_argument("sweep_dir", nargs="?", help="a compare sweep's directory")
    parser.add_argument("--runs", nargs="+", help="run directories instead of a sweep")
    parser.add_argument("--mode", default="active", help="the sweep's forgetting mode")
    parser.add_argument("--first-day", type=int, default=1,
                        help="pooled ratio over days >= N, 1-based")
    parser.add_argument("--first-frames", type=int, default=0,
                        help="per-day rotations, and that of each run's first N frames")
    args = parser.parse_args(argv[1:])
    if (args.sweep_dir is None) == (args.runs is None):
        parser.error("give either a sweep directory or --runs")
    omnicml, first_day, first_frames = args.omnicml, args.first_day, args.first_frames
    if args.runs:
        runs = args.runs
    else:
        base = os.path.join(args.sweep_dir, "runs")
        runs = sorted((os.path.join(base, j, args.mode) for j in os.listdir(base)
                       if os.path.isfile(os.path.join(base, j, args.mode, "frames.csv"))),
                      key=lambda p: [int(t) if t.isdigit() else t
                                     for t in re.split(r"(\d+)", p)])
    if not runs:
        sys.exit("nees_frame_table: no run directories with frames.csv")
    print("| run | frames with NEES / all | mean error world / aligned (m) | rotation (deg) | "
          "shift (m) | NEES median world / aligned | NEES p95 world / aligned |")
    print("|---|---|---|---|---|---|---|")
    rows = []
    days, firsts, views = [], [], []
    e2_all = tr_all = 0.0
    for run in runs:
        w = evaluate(omnicml, run, "none")
        a = evaluate(omnicml, run, "se2")
        frames = read_frames(run)
        e2, tr = pooled(frames, first_day)
        if first_frames > 0:
            d, f, v = day_rotations(frames, first_frames)
            days += d
            firsts.append((f, d))
            views.append(v)
        e2_all += e2
        tr_all += tr
        rows.append((w, a))
        name = os.path.basename(os.path.dirname(os.path.abspath(run)))
        print(f"| {name} | {w['nees_frames']} | {w['mean_err']:.3f} / {a['mean_err']:.3f} | "
              f"{a['rot_deg']:+.2f} | {a['shift_m']:.2f} | {w['nees_med']:.2f} / "
              f"{a['nees_med']:.2f} | {w['nees_p95']:.1f} / {a['nees_p95']:.1f} |")
    inband = lambda v, b: b[0] <= v <= b[1]
    ratio = e2_all / tr_all if tr_all > 0 else float("nan")
    print()
    print(f"runs: {len(rows)}")
    for label, k in (("world", 0), ("aligned (se2)", 1)):
        med = sorted(r[k]["nees_med"] for r in rows)
        print(f"{label}: NEES median in [0.7, 2.8] on "
              f"{sum(inband(r[k]['nees_med'], BAND_MEDIAN) for r in rows)}, p95 in [3, 12] on "
              f"{sum(inband(r[k]['nees_p95'], BAND_P95) for r in rows)}; median of the runs' "
              f"medians {med[len(med) // 2]:.2f} (range {med[0]:.2f}-{med[-1]:.2f})")
    print(f"pooled over every frame with a NEES (days >= {first_day}): mean e^2 / mean trace C "
          f"= {ratio:.3f}; runs whose world NEES median would be in [0.7, 2.8] with every "
          f"covariance scaled by it: "
          f"{sum(inband(r[0]['nees_med'] / ratio, BAND_MEDIAN) for r in rows)}")
    if first_frames > 0:
        sums = [rot + head for rot, head in days]
        mean_sum = sum(sums) / len(sums)
        sd_sum = math.sqrt(sum((v - mean_sum) ** 2 for v in sums) / len(sums))
        same = sum(1 for f, d in firsts
                   if d and f * sum(rot for rot, _ in d) > 0)
        print(f"per-day rigid fits, days >= 2 ({len(days)} day fits): mean |rotation| "
              f"{sum(abs(r) for r, _ in days) / len(days):.1f} deg, largest "
              f"{max(abs(r) for r, _ in days):.1f}; rotation + mean heading error "
              f"{mean_sum:+.1f} +- {sd_sum:.1f} deg; first {first_frames} frames: mean |rotation| "
              f"{sum(abs(f) for f, _ in firsts) / len(firsts):.1f} deg, same sign as days >= 2 "
              f"on {same} of {len(firsts)} runs; views after them: mean "
              f"{sum(views) / len(views):.0f} (range {min(views)}-{max(views)})")


if __name__ == "__main__":
    main(sys.argv)
