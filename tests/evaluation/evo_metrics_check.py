#!/usr/bin/env python3
"""Checks `omnicml evaluate`'s APE and RPE against an independent numpy computation.

Writes a random planar ground truth and a drifting, noisy estimate with jittered stamps
(some ground-truth poses removed, so a few frames find none within --max-time-diff) as
TUM files, runs `omnicml evaluate --estimate --groundtruth`, and recomputes evo's figures
here with homogeneous 3x3 matrices: association by nearest stamp (evo
matching_time_indices), APE RMSE of the translation, RPE pairs by path length on the
reference (evo filter_pairs_by_path, all_pairs=False), E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j).
Usage: evo_metrics_check.py OMNICML_BINARY
"""
import math
import os
import re
import subprocess
import sys
import tempfile

import numpy as np


def se2(x, y, yaw):
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


def write_tum(path, stamps, poses):
    with open(path, "w") as f:
        f.write("# stamp x y z qx qy qz qw\n")
        for t, (x, y, yaw) in zip(stamps, poses):
            f.write(f"{t!r} {x!r} {y!r} 0 0 0 {math.sin(yaw / 2)!r} {math.cos(yaw / 2)!r}\n")


def stats(values):
    v = np.asarray(values)
    return {"count": v.size, "rmse": math.sqrt(np.mean(v ** 2)), "mean": np.mean(v),
            "median": np.median(v), "std": np.std(v), "min": np.min(v), "max": np.max(v)}


def main():
    binary = sys.argv[1]
    rng = np.random.default_rng(7)
    n = 400
    stamps = 100.0 + 0.1 * np.arange(n)
    yaw = np.cumsum(rng.normal(0, 0.05, n))
    step = 0.12 + 0.05 * rng.random(n)
    xy = np.cumsum(np.stack([step * np.cos(yaw), step * np.sin(yaw)], 1), 0)
    truth = np.column_stack([xy, yaw])
    # Estimate: noise plus a slowly growing offset and heading drift.
    est = truth.copy()
    est[:, 0] += rng.normal(0, 0.05, n) + 0.002 * np.arange(n)
    est[:, 1] += rng.normal(0, 0.05, n)
    est[:, 2] += rng.normal(0, 0.01, n) + 0.0005 * np.arange(n)
    est_stamps = stamps + rng.uniform(-0.004, 0.004, n)
    keep = np.ones(n, bool)
    keep[rng.choice(n, 25, replace=False)] = False  # ground truth missing there
    ref_stamps, ref = stamps[keep], truth[keep]
    max_diff, delta = 0.01, 1.5

    # Association as evo: each estimate pose, nearest reference stamp within max_diff.
    pairs = []
    for i, t in enumerate(est_stamps):
        d = np.abs(ref_stamps - t)
        j = int(np.argmin(d))
        if d[j] <= max_diff:
            pairs.append((i, j))
    P = [se2(*est[i]) for i, _ in pairs]
    Q = [se2(*ref[j]) for _, j in pairs]
    ape = [np.linalg.norm(p[:2, 2] - q[:2, 2]) for p, q in zip(P, Q)]
    ids, path = [], 0.0
    for k in range(len(Q)):
        if k > 0:
            path += np.linalg.norm(Q[k][:2, 2] - Q[k - 1][:2, 2])
        if path >= delta:
            ids.append(k)
            path = 0.0
    rpe_t, rpe_r = [], []
    for a, b in zip(ids, ids[1:]):
        E = np.linalg.inv(np.linalg.inv(Q[a]) @ Q[b]) @ (np.linalg.inv(P[a]) @ P[b])
        rpe_t.append(np.linalg.norm(E[:2, 2]))
        rpe_r.append(abs(math.degrees(math.atan2(E[1, 0], E[0, 0]))))

    with tempfile.TemporaryDirectory() as tmp:
        write_tum(os.path.join(tmp, "est.tum"), est_stamps, est)
        write_tum(os.path.join(tmp, "gt.tum"), ref_stamps, ref)
        out = subprocess.run(
            [binary, "evaluate", "--estimate", os.path.join(tmp, "est.tum"), "--groundtruth",
             os.path.join(tmp, "gt.tum"), "--max-time-diff", str(max_diff), "--rpe-delta-m",
             str(delta), "--out", os.path.join(tmp, "eval.html")],
            capture_output=True, text=True)
        if out.returncode != 0:
            print(out.stdout, out.stderr)
            return 1
        text = out.stdout

    expected = {"APE position": (stats(ape), 3), "RPE translation": (stats(rpe_t), 3),
                "RPE rotation": (stats(rpe_r), 2)}
    failures = 0
    for name, (s, decimals) in expected.items():
        m = re.search(rf"^{name}\s+\S+(?: per \S+ m)?\s+(\d+)\s+(.*)$", text, re.M)
        if not m:
            print(f"no '{name}' row in the output:\n{text}")
            return 1
        count = int(m.group(1))
        values = [float(v) for v in m.group(2).split()]
        if count != s["count"]:
            print(f"{name}: count {count}, numpy {s['count']}")
            failures += 1
        for key, got in zip(["rmse", "mean", "median", "std", "min", "max"], values):
            if abs(got - s[key]) > 0.51 * 10 ** -decimals + 1e-12:
                print(f"{name} {key}: omnicml {got}, numpy {s[key]:.6f}")
                failures += 1
    matched = re.search(r"(\d+) of (\d+) frames associated", text)
    if not matched or int(matched.group(1)) != len(pairs):
        print(f"associated frames: omnicml {matched and matched.group(1)}, numpy {len(pairs)}")
        failures += 1
    if len(ids) < 10 or len(pairs) >= n:
        print("test trajectory too short or nothing left unassociated")
        failures += 1
    print(f"APE RMSE {stats(ape)['rmse']:.4f} m over {len(pairs)} frames, RPE "
          f"{len(ids) - 1} pairs: translation RMSE {stats(rpe_t)['rmse']:.4f} m, rotation RMSE "
          f"{stats(rpe_r)['rmse']:.3f} deg; {'ok' if failures == 0 else 'FAILED'}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
