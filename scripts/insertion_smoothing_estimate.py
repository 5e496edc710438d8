#!/usr/bin/env python3
"""How much closer to the truth a map insertion would be if the map update carried an
estimate refined by the frames of its delay: for every unimodal frame t whose frame t + L
is unimodal in the same session, the filtered estimate at t is fused in information form
with the estimate at t + L carried back by the odometry increment (its covariance plus
the increment's variance under Thrun's a1..a4, as if independent). Prints the filtered
and the fused position errors against the truth (mean and median) per run directory.
An offline estimate of a fixed-lag smoother, not the smoother itself.

Usage: scripts/insertion_smoothing_estimate.py [--lag L] [--motion a1,a2,a3,a4]
           [--first-session S] RUN_DIR...
"""
import argparse
import csv
import math
import os
import statistics
import sys


def wrap(a):
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def fuse(xf, cf, xb, cb):
    """Information-form fusion of two 2-D Gaussians (covariances as (xx, xy, yy))."""
    def inv(c):
        det = c[0] * c[2] - c[1] * c[1]
        return (c[2] / det, -c[1] / det, c[0] / det)
    a, b = inv(cf), inv(cb)
    i = (a[0] + b[0], a[1] + b[1], a[2] + b[2])
    v = (a[0] * xf[0] + a[1] * xf[1] + b[0] * xb[0] + b[1] * xb[1],
         a[1] * xf[0] + a[2] * xf[1] + b[1] * xb[0] + b[2] * xb[1])
    ci = inv(i)
    return (ci[0] * v[0] + ci[1] * v[1], ci[1] * v[0] + ci[2] * v[1])


def run(path, lag, motion, first_session):
    a1, a2, a3, _ = motion
    rows = [r for r in csv.DictReader(open(os.path.join(path, "frames.csv")))
            if int(r["session"]) >= first_session]
    f = lambda r, k: float(r[k])
    filtered, fused = [], []
    for i in range(len(rows) - lag):
        r, q = rows[i], rows[i + lag]
        if r["session"] != q["session"] or r["unimodal"] != "1" or q["unimodal"] != "1":
            continue
        if r["truth_x_m"] == "" or r["cov_xx_m2"] == "" or q["cov_xx_m2"] == "":
            continue
        phi = f(r, "odom_phi_rad")
        dx, dy = f(q, "odom_x_m") - f(r, "odom_x_m"), f(q, "odom_y_m") - f(r, "odom_y_m")
        lx = math.cos(phi) * dx + math.sin(phi) * dy
        ly = -math.sin(phi) * dx + math.cos(phi) * dy
        dphi = wrap(f(q, "odom_phi_rad") - phi)
        back = wrap(f(q, "est_phi_rad") - dphi)
        xb = (f(q, "est_x_m") - (math.cos(back) * lx - math.sin(back) * ly),
              f(q, "est_y_m") - (math.sin(back) * lx + math.cos(back) * ly))
        trans = math.hypot(lx, ly)
        var = a3 * trans ** 2 + trans ** 2 * (a1 * dphi ** 2 + a2 * trans ** 2)
        cf = (f(r, "cov_xx_m2"), f(r, "cov_xy_m2"), f(r, "cov_yy_m2"))
        cb = (f(q, "cov_xx_m2") + var, f(q, "cov_xy_m2"), f(q, "cov_yy_m2") + var)
        xf = (f(r, "est_x_m"), f(r, "est_y_m"))
        xs = fuse(xf, cf, xb, cb)
        t = (f(r, "truth_x_m"), f(r, "truth_y_m"))
        filtered.append(math.hypot(xf[0] - t[0], xf[1] - t[1]))
        fused.append(math.hypot(xs[0] - t[0], xs[1] - t[1]))
    return filtered, fused


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="+")
    p.add_argument("--lag", type=int, default=8)
    p.add_argument("--motion", default="0.05,0.01,0.05,0.01")
    p.add_argument("--first-session", type=int, default=0)
    a = p.parse_args()
    motion = [float(x) for x in a.motion.split(",")]
    if len(motion) != 4:
        print("--motion: four values a1,a2,a3,a4", file=sys.stderr)
        return 2
    print("| run | frames | filtered mean / median (m) | fused mean / median (m) | median change |")
    print("|---|---|---|---|---|")
    for path in a.runs:
        e, s = run(path, a.lag, motion, a.first_session)
        if not e:
            print(f"| {path} | 0 | - | - | - |")
            continue
        print(f"| {path} | {len(e)} | {statistics.mean(e):.3f} / {statistics.median(e):.3f} | "
              f"{statistics.mean(s):.3f} / {statistics.median(s):.3f} | "
              f"{100 * (statistics.median(s) / statistics.median(e) - 1):+.1f} % |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
