#!/usr/bin/env python3
"""Writes a copy of an omnicml log session in which the robot stands still at given frames.

Usage: park_session.py SRC_SESSION_DIR DST_SESSION_DIR --at 500,1500,2500 [--frames 600]

Row k of frames.csv (0-based, after the header) listed in --at is repeated --frames times:
same image, odometry and ground truth, a robot parked there. Stamps are renumbered with
the session's first stamp gap so that they keep increasing. Images are hard-linked (copied
across file systems); session.yaml is copied unchanged. docs/results.md "The map against the frame rate".
"""
import argparse, os, shutil

import session_frames

ap = argparse.ArgumentParser()
ap.add_argument("src"); ap.add_argument("dst")
ap.add_argument("--at", required=True, help="comma-separated 0-based rows to park at")
ap.add_argument("--frames", type=int, default=600, help="frames spent at each of them")
a = ap.parse_args()
if a.frames < 1:
    ap.error(f"--frames must be >= 1, got {a.frames}")
at = {int(v) for v in a.at.split(",") if v.strip()}
header_lines, head, body = session_frames.read(a.src)
if "stamp_s" not in head:
    raise SystemExit(f"{a.src}/frames.csv: no stamp_s column")
bad = sorted(k for k in at if not 0 <= k < len(body))
if bad:
    raise SystemExit(f"--at: rows {bad} outside the session's {len(body)} rows")
it = head.index("stamp_s")
t0 = float(body[0][it])
dt = float(body[1][it]) - t0 if len(body) > 1 else 1.0
out = []
for k, r in enumerate(body):
    for _ in range(a.frames if k in at else 1):
        rr = list(r)
        rr[it] = repr(t0 + dt * len(out))
        out.append(rr)
os.makedirs(a.dst, exist_ok=True)
session_frames.write(a.dst, header_lines, head, out)
for name in os.listdir(a.src):
    if name == "frames.csv": continue
    src = os.path.join(os.path.abspath(a.src), name)
    dst = os.path.join(a.dst, name)
    if name == "session.yaml":
        shutil.copyfile(src, dst)
    elif not os.path.exists(dst):
        # A hard link (a copy across file systems), not a symbolic link: the engine reads
        # no image through a link that leads out of the log directory.
        try:
            os.link(src, dst)
        except OSError:
            shutil.copy2(src, dst)
print(f"wrote {len(out)} frames ({len(body)} rows, {len(at)} parked for {a.frames}) to {a.dst}")
