#!/usr/bin/env python3
"""Writes a copy of an omnicml log session whose odometry drifts, for robustness runs.

Usage: drift_session.py SRC_SESSION_DIR DST_SESSION_DIR [--scale 0.03] [--deg-per-m 2]
                        [--start global|keep] [--day-label LABEL]

Each odometry increment (in the robot frame of the previous odometry pose) is scaled by
1 + scale in translation, and the heading gains deg_per_m degrees per metre travelled.
Images are symlinked, ground truth is kept, session.yaml is copied with the start mode
set to `global` (no prior) unless --start keep.
"""
import argparse, math, os, re

import session_frames

ap = argparse.ArgumentParser()
ap.add_argument("src"); ap.add_argument("dst")
ap.add_argument("--scale", type=float, default=0.03)
ap.add_argument("--deg-per-m", type=float, default=2.0)
ap.add_argument("--start", choices=["global", "keep"], default="global")
ap.add_argument("--day-label", default=None)
a = ap.parse_args()
os.makedirs(a.dst, exist_ok=True)
header_lines, head, body = session_frames.read(a.src)
ix, iy, ip = head.index("odom_x_m"), head.index("odom_y_m"), head.index("odom_phi_rad")
out = []
prev = None
cur = None
for r in body:
    x, y, p = float(r[ix]), float(r[iy]), float(r[ip])
    if prev is None:
        cur = [x, y, p]
    else:
        dx, dy = x - prev[0], y - prev[1]
        c, s = math.cos(prev[2]), math.sin(prev[2])
        fx, fy = c * dx + s * dy, -s * dx + c * dy  # increment in the previous robot frame
        dphi = math.remainder(p - prev[2], 2 * math.pi)
        dist = math.hypot(fx, fy)
        fx, fy = fx * (1 + a.scale), fy * (1 + a.scale)
        dphi += math.radians(a.deg_per_m) * dist
        c2, s2 = math.cos(cur[2]), math.sin(cur[2])
        cur = [cur[0] + c2 * fx - s2 * fy, cur[1] + s2 * fx + c2 * fy,
               math.remainder(cur[2] + dphi, 2 * math.pi)]
    prev = [x, y, p]
    r = list(r)
    r[ix], r[iy], r[ip] = f"{cur[0]:.6f}", f"{cur[1]:.6f}", f"{cur[2]:.6f}"
    out.append(r)
session_frames.write(a.dst, header_lines, head, out)
for name in os.listdir(a.src):
    if name in ("frames.csv", "session.yaml"): continue
    src = os.path.join(os.path.abspath(a.src), name)
    dst = os.path.join(a.dst, name)
    if not os.path.exists(dst): os.symlink(src, dst)
y = open(os.path.join(a.src, "session.yaml")).read()
if a.start == "global":
    # Replace the start block with a global start.
    y = re.sub(r"(?ms)^start:.*?(?=^\S|\Z)", "start:\n  mode: global\n", y)
if a.day_label:
    y = re.sub(r"(?m)^day_label:.*$", f"day_label: {a.day_label}", y)
open(os.path.join(a.dst, "session.yaml"), "w").write(y)
