#!/usr/bin/env python3
"""What an active map holds against the passive map of the same input, from the maps'
JSON (`omnicml export MAP --out MAP.json --no-events`): views, views matched in the last
session, stranded views (never matched after the session that made them, made at least
--min-later sessions before the last), and the bound on active / passive if active kept
only what the last session matched. With --frames (the active run's frames.csv), where
the stranded views lie: distance of their strongest component to the nearest true
position of the later sessions (<= 0.5 m, 0.5-1.5 m, beyond).

Usage: scripts/map_composition.py [--min-later N] [--frames FRAMES.csv] ACTIVE.json PASSIVE.json
"""
import argparse
import csv
import json
import math
import sys


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("active")
    p.add_argument("passive")
    p.add_argument("--min-later", type=int, default=4)
    p.add_argument("--frames")
    a = p.parse_args()
    act = json.load(open(a.active))["views"]
    pas = json.load(open(a.passive))["views"]
    last = max(v["stats"]["last_seen_session"] for v in pas + act)
    matched_last = sum(v["stats"]["last_seen_session"] == last for v in act)
    stranded = [v for v in act if v["stats"]["last_seen_session"] == v["stats"]["created_session"]
                and v["stats"]["created_session"] <= last - a.min_later]
    print(f"active views {len(act)}, matched in the last session {matched_last}, "
          f"stranded {len(stranded)}; passive views {len(pas)}; active / passive "
          f"{len(act) / len(pas):.2f}; bound {matched_last / len(pas):.2f}")
    if a.frames:
        truth = {}
        for r in csv.DictReader(open(a.frames)):
            if r["truth_x_m"] != "":
                truth.setdefault(int(r["session"]), []).append(
                    (float(r["truth_x_m"]), float(r["truth_y_m"])))
        near = mid = far = 0
        for v in stranded:
            c = max(v["components"], key=lambda c: c["weight"])
            x, y = c["mean"][0], c["mean"][1]
            d = min((math.hypot(x - tx, y - ty) for s, pts in truth.items()
                     if s > v["stats"]["created_session"] for tx, ty in pts), default=math.inf)
            near += d <= 0.5
            mid += 0.5 < d <= 1.5
            far += d > 1.5
        print(f"stranded within 0.5 m of a later true position {near}, 0.5-1.5 m {mid}, "
              f"beyond {far}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
