#!/usr/bin/env python3
"""Map growth of a compare run directory as an SVG: views in the map against the frame,
one line per forgetting mode (the README's and results.md's demo figure).

Reads DIR/{passive,active,static}/frames.csv (column `views`).

Usage: scripts/map_growth_svg.py COMPARE_DIR OUT.svg
"""
import csv
import sys

COLOURS = {"passive": "#1f77b4", "active": "#d62728", "static": "#2ca02c"}


def main() -> int:
    if len(sys.argv) != 3:
        print(__doc__.strip().splitlines()[-1], file=sys.stderr)
        return 2
    run, out = sys.argv[1].rstrip("/"), sys.argv[2]
    series = {}
    for mode in COLOURS:
        path = f"{run}/{mode}/frames.csv"
        try:
            with open(path, newline="") as f:
                series[mode] = [int(r["views"]) for r in csv.DictReader(f)]
        except OSError as e:
            print(f"{path}: {e.strerror}", file=sys.stderr)
            return 2
        except (KeyError, ValueError):
            print(f"{path}: no integer column 'views'", file=sys.stderr)
            return 2
    n = max(len(v) for v in series.values())
    vmax = max(max(v) for v in series.values())
    ystep = 500 if vmax > 1000 else 100
    ymax = (vmax // ystep + 1) * ystep
    w, h, left, top, pw, ph = 980, 320, 70, 30, 880, 240
    px = lambda i: left + pw * i / max(n - 1, 1)
    py = lambda v: top + ph * (1 - v / ymax)
    body = [f'<rect width="{w}" height="{h}" fill="white"/>',
            f'<text x="{left + pw / 2}" y="18" text-anchor="middle" font-weight="bold">'
            f'Map growth</text>',
            f'<rect x="{left}" y="{top}" width="{pw}" height="{ph}" fill="none" stroke="black"/>']
    for v in range(0, ymax + 1, ystep):
        body.append(f'<line x1="{left}" y1="{py(v):.1f}" x2="{left + pw}" y2="{py(v):.1f}" '
                    f'stroke="#dddddd"/><text x="{left - 6}" y="{py(v) + 4:.1f}" '
                    f'text-anchor="end">{v}</text>')
    for i in range(0, n, 1000):
        body.append(f'<text x="{px(i):.1f}" y="{top + ph + 16}" text-anchor="middle">{i}</text>')
    body.append(f'<text x="{left + pw / 2}" y="{top + ph + 34}" text-anchor="middle">frame</text>')
    body.append(f'<text x="16" y="{top + ph / 2}" text-anchor="middle" '
                f'transform="rotate(-90 16 {top + ph / 2})">reference views</text>')
    for k, (mode, vals) in enumerate(series.items()):
        step = max(1, len(vals) // 1500)
        pts = " ".join(f"{px(i):.1f},{py(vals[i]):.1f}" for i in range(0, len(vals), step))
        body.append(f'<polyline points="{pts}" fill="none" stroke="{COLOURS[mode]}" '
                    f'stroke-width="1.5"/>')
        y = top + 16 + 16 * k
        body.append(f'<line x1="{left + 12}" y1="{y - 4}" x2="{left + 32}" y2="{y - 4}" '
                    f'stroke="{COLOURS[mode]}" stroke-width="2"/><text x="{left + 38}" y="{y}">'
                    f'{mode} ({vals[-1]} at the last frame)</text>')
    svg = (f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" '
           f'font-family="sans-serif" font-size="11">' + "\n".join(body) + "</svg>\n")
    with open(out, "w") as f:
        f.write(svg)
    return 0


if __name__ == "__main__":
    sys.exit(main())
