#!/usr/bin/env python3
"""Tables of a layout-change sweep (datasets/sweeps/layout_changes_store_large.yaml).

Reads SWEEP_DIR/summary_days.csv (written by `omnicml sweep` / `omnicml collect`) and prints
markdown tables for docs/results.md "Layout changes":

1. per intensity (the sweep input) and forgetting mode: the mean position error over days
   2..N (the days after the survey), frame-weighted, as the mean and the worst over seeds;
   frames counted (localized / all); the position NEES median averaged over those days;
   the map size at the end (mean over seeds);
2. the check of docs/results.md: static's last-day error over its day-2 error (mean over
   seeds); the lowest intensity where that ratio is >= 2; there active's mean error over
   the last three days against static's and passive's, and active's map against passive's.

With --curve-svg PATH it also writes the curve itself: static, passive and active mean
error over days 2..N against the intensity (mean over seeds solid, worst seed dashed)
beside the map size at the end (mean over seeds). A sweep of several configurations needs
--config NAME (the configuration file's name without .yaml): the tables are of one.

With --active-from DIR the active rows come from another sweep's summary_days.csv (a
`run` sweep of active forgetting under an option that changes active only), and static
and passive from SWEEP_DIR: the same protocol, inputs and seeds.

Usage: scripts/layout_change_table.py SWEEP_DIR [--config NAME] [--curve-svg PATH]
                                      [--active-from DIR]
"""
import argparse
import csv
import math
import sys
from collections import defaultdict


COLOURS = {"static": "#7f7f7f", "passive": "#1f77b4", "active": "#d62728"}


def panel(title, y_label, xs, series, x0, width=460, height=300):
    """One SVG panel (a <g> at x offset x0): lines over xs (intensities, placed evenly so
    the fine grid near 0 stays readable), series = [(mode, values, dashed)]."""
    left, top, pw, ph = x0 + 60, 34, width - 80, height - 80
    ymax = max(v for _, vals, _ in series for v in vals if math.isfinite(v)) * 1.08
    step = 10 ** math.floor(math.log10(ymax / 4))
    step *= 5 if ymax / step > 20 else 2 if ymax / step > 8 else 1
    px = lambda i: left + pw * i / max(len(xs) - 1, 1)
    py = lambda v: top + ph * (1 - v / ymax)
    out = [f'<text x="{left + pw / 2:.1f}" y="18" text-anchor="middle" font-size="13" '
           f'font-weight="bold">{title}</text>',
           f'<rect x="{left}" y="{top}" width="{pw}" height="{ph}" fill="none" stroke="black"/>']
    tick = 0.0
    while tick <= ymax:
        out.append(f'<line x1="{left}" y1="{py(tick):.1f}" x2="{left + pw}" y2="{py(tick):.1f}" '
                   f'stroke="#dddddd"/><text x="{left - 6}" y="{py(tick) + 4:.1f}" '
                   f'text-anchor="end">{tick:g}</text>')
        tick += step
    for i, x in enumerate(xs):
        out.append(f'<text x="{px(i):.1f}" y="{top + ph + 16}" text-anchor="middle">{x:g}</text>')
    out.append(f'<text x="{left + pw / 2:.1f}" y="{top + ph + 34}" text-anchor="middle">'
               f'layout_intensity p</text>')
    out.append(f'<text x="{x0 + 14}" y="{top + ph / 2:.1f}" text-anchor="middle" '
               f'transform="rotate(-90 {x0 + 14} {top + ph / 2:.1f})">{y_label}</text>')
    for mode, vals, dashed in series:
        pts = " ".join(f"{px(i):.1f},{py(v):.1f}" for i, v in enumerate(vals) if math.isfinite(v))
        dash = ' stroke-dasharray="5,4"' if dashed else ""
        out.append(f'<polyline points="{pts}" fill="none" stroke="{COLOURS[mode]}" '
                   f'stroke-width="2"{dash}/>')
    for k, mode in enumerate(COLOURS):
        y = top + 14 + 16 * k
        out.append(f'<line x1="{left + 10}" y1="{y - 4}" x2="{left + 30}" y2="{y - 4}" '
                   f'stroke="{COLOURS[mode]}" stroke-width="2"/><text x="{left + 36}" y="{y}">'
                   f'{mode}</text>')
    return out


def write_curve(path, inputs, summary):
    xs = [float(i.lstrip("i")) for i in inputs]
    err, views = [], []
    for mode in COLOURS:
        got = [summary.get((i, mode)) for i in inputs]
        err.append((mode, [g["mean"] if g else math.nan for g in got], False))
        err.append((mode, [g["worst"] if g else math.nan for g in got], True))
        views.append((mode, [g["views"] if g else math.nan for g in got], False))
    body = panel("mean error, days 2-N (solid: mean, dashed: worst seed)", "error (m)", xs, err, 0)
    body += panel("views at the end (mean over seeds)", "views", xs, views, 480)
    svg = ('<svg xmlns="http://www.w3.org/2000/svg" width="960" height="300" '
           'font-family="sans-serif" font-size="11"><rect width="960" height="300" fill="white"/>'
           + "\n".join(body) + "</svg>\n")
    with open(path, "w") as f:
        f.write(svg)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument("sweep_dir")
    ap.add_argument("--config", help="the configuration file's name without .yaml")
    ap.add_argument("--curve-svg", help="also write the curve to this SVG")
    ap.add_argument("--active-from", help="take the active rows from this sweep directory")
    a = ap.parse_args()  # a bad command line exits 2 with its usage
    curve, config = a.curve_svg, a.config
    path = a.sweep_dir.rstrip("/") + "/summary_days.csv"
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
        if a.active_from:
            other = a.active_from.rstrip("/") + "/summary_days.csv"
            path = other
            with open(other, newline="") as f:
                active = [r for r in csv.DictReader(f) if r["mode"] == "active"]
            if not active:
                print(f"{other}: no active runs", file=sys.stderr)
                return 2
            for r in active:
                r["config"] = ""
            rows = [r for r in rows if r["mode"] != "active"] + active
            path = a.sweep_dir.rstrip("/") + "/summary_days.csv"
    except OSError as e:
        print(f"{path}: {e.strerror}", file=sys.stderr)
        return 2

    def config_name(r):
        c = (r.get("config") or "").rsplit("/", 1)[-1]
        return c[:-5] if c.endswith(".yaml") else c

    names = sorted({config_name(r) for r in rows})
    if config is not None:
        rows = [r for r in rows if config_name(r) == config]
        if not rows:
            print(f"{path}: no runs with config {config!r} (configs: {', '.join(names)})",
                  file=sys.stderr)
            return 2
    elif len(names) > 1:
        print(f"{path}: runs of {len(names)} configs ({', '.join(names)}); pass --config NAME",
              file=sys.stderr)
        return 2
    # (input, mode, seed) -> list of day rows, by day.
    runs = defaultdict(dict)
    for r in rows:
        runs[(r["input"], r["mode"], int(r["seed"]))][int(r["day"])] = r

    def num(v):
        return float(v) if v not in ("", None) else math.nan

    def weighted(days, first, last):
        """Frame-weighted mean error over days first..last; (error, localized, frames)."""
        s = n = frames = 0
        for d in range(first, last + 1):
            r = days.get(d)
            if r is None:
                continue
            frames += int(r["frames"])
            loc = int(r["frames_localized"])
            e = num(r["error_mean_m"])
            if loc > 0 and math.isfinite(e):
                s += e * loc
                n += loc
        return (s / n if n else math.nan), n, frames

    inputs = sorted({k[0] for k in runs}, key=lambda s: float(s.lstrip("i")) if s.lstrip("i").replace(".", "").isdigit() else s)
    modes = ["static", "passive", "active"]
    last_day = max(int(r["day"]) for r in rows)
    print(f"Days 2-{last_day} (after the survey day), per seed frame-weighted, then over seeds:\n")
    print("| intensity | mode | seeds | frames (localized / all) | mean error (m) | worst seed (m) | NEES xy median | views at end |")
    print("|---|---|---|---|---|---|---|---|")
    summary = {}
    for inp in inputs:
        for mode in modes:
            seeds = sorted(k[2] for k in runs if k[0] == inp and k[1] == mode)
            if not seeds:
                continue
            errs, loc_total, frames_total, nees, views = [], 0, 0, [], []
            day2, lastd, last3 = [], [], []
            for s in seeds:
                days = runs[(inp, mode, s)]
                e, loc, fr = weighted(days, 2, last_day)
                errs.append(e)
                loc_total += loc
                frames_total += fr
                nees += [num(days[d]["nees_xy_median"]) for d in range(2, last_day + 1) if d in days]
                views.append(int(days[max(days)]["views_at_end"]))
                day2.append(weighted(days, 2, 2)[0])
                lastd.append(weighted(days, last_day, last_day)[0])
                last3.append(weighted(days, last_day - 2, last_day)[0])
            finite_nees = [v for v in nees if math.isfinite(v)]
            mean = sum(errs) / len(errs)
            summary[(inp, mode)] = dict(
                mean=mean, worst=max(errs), views=sum(views) / len(views),
                day2=sum(day2) / len(day2), last=sum(lastd) / len(lastd),
                last3=sum(last3) / len(last3), seeds=len(seeds))
            print(f"| {inp.lstrip('i')} | {mode} | {len(seeds)} | {loc_total} / {frames_total} | "
                  f"{mean:.3f} | {max(errs):.3f} | "
                  f"{(sum(finite_nees) / len(finite_nees)) if finite_nees else math.nan:.2f} | "
                  f"{sum(views) / len(views):.0f} |")
    print("\nStatic's last day against its day 2, and at each intensity the last three days:\n")
    print(f"| intensity | static day 2 (m) | static day {last_day} (m) | ratio | "
          f"last 3 days static / passive / active (m) | active / static | active / passive | "
          f"views active / passive |")
    print("|---|---|---|---|---|---|---|---|")
    lowest = None
    for inp in inputs:
        st, pa, ac = (summary.get((inp, m)) for m in modes)
        if not (st and pa and ac):
            continue
        ratio = st["last"] / st["day2"]
        if lowest is None and ratio >= 2:
            lowest = inp
        print(f"| {inp.lstrip('i')} | {st['day2']:.3f} | {st['last']:.3f} | {ratio:.2f} | "
              f"{st['last3']:.3f} / {pa['last3']:.3f} / {ac['last3']:.3f} | "
              f"{ac['last3'] / st['last3']:.2f} | {ac['last3'] / pa['last3']:.2f} | "
              f"{ac['views']:.0f} / {pa['views']:.0f} = {ac['views'] / pa['views']:.2f} |")
    if curve:
        write_curve(curve, [i for i in inputs if (i, "active") in summary], summary)
    if lowest is None:
        print("\nNo intensity where static's last-day error reaches twice its day-2 error.")
    else:
        st, pa, ac = (summary[(lowest, m)] for m in modes)
        checks = [
            ("active <= 0.6 x static (last 3 days)", ac["last3"] <= 0.6 * st["last3"]),
            ("active <= 1.1 x passive (last 3 days)", ac["last3"] <= 1.1 * pa["last3"]),
            ("active map <= 0.5 x passive map", ac["views"] <= 0.5 * pa["views"]),
        ]
        print(f"\nLowest intensity with static's day {last_day} >= 2 x its day 2: "
              f"{lowest.lstrip('i')}")
        for name, ok in checks:
            print(f"- {name}: {'met' if ok else 'NOT met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
