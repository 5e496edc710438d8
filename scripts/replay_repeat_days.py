#!/usr/bin/env python3
"""Builds a long compare directory by repeating a compare directory's runs REPS times
(frames, sessions and view ids shifted), to measure the replay on a long run.
Usage: replay_repeat_days.py COMPARE_DIR OUT_DIR REPS
"""
import csv, os, shutil, sys
src, dst, reps = sys.argv[1], sys.argv[2], int(sys.argv[3])
for mode in ("passive", "active", "static"):
    os.makedirs(os.path.join(dst, mode), exist_ok=True)
    shutil.copy(os.path.join(src, mode, "config.yaml"), os.path.join(dst, mode, "config.yaml"))
    rows = list(csv.reader(open(os.path.join(src, mode, "frames.csv"))))
    head, rows = rows[0], rows[1:]
    ci = {c: i for i, c in enumerate(head)}
    n, days = len(rows), 1 + max(int(r[0]) for r in rows)
    with open(os.path.join(dst, mode, "frames.csv"), "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n"); w.writerow(head)
        for k in range(reps):
            for r in rows:
                r2 = list(r)
                r2[ci["session"]] = str(int(r[ci["session"]]) + k * days)
                r2[ci["global_frame"]] = str(int(r[ci["global_frame"]]) + k * n)
                w.writerow(r2)
    ev = list(csv.reader(open(os.path.join(src, mode, "events.csv"))))
    eh, ev = ev[0], ev[1:]
    with open(os.path.join(dst, mode, "events.csv"), "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n"); w.writerow(eh)
        for k in range(reps):
            for e in ev:
                e2 = list(e)
                e2[1] = str(int(e[1]) + k * n); e2[2] = str(int(e[2]) + k * days)
                e2[3] = str(int(e[3]) + k * 100000)
                w.writerow(e2)
