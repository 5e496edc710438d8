#!/usr/bin/env python3
"""Checks the module layering: no include runs back up the module order.

The order is OMNICML_MODULES of the top-level CMakeLists.txt (plus ros, appended there
when ROS is found). A file of module M (src/M/, include/omnicml/M/) may include
"omnicml/N/..." only when N is M or comes before M. Prints one line per violation
("<file>:<line>: <module> includes <other>, which comes after it") and exits 1, or 0.

    scripts/check_layering.py [REPO_ROOT]
"""
import pathlib
import re
import sys


def module_order(root):
    text = (root / "CMakeLists.txt").read_text()
    m = re.search(r"set\(OMNICML_MODULES([^)]*)\)", text)
    if not m:
        sys.exit("check_layering: OMNICML_MODULES not found in CMakeLists.txt")
    order = m.group(1).split()
    if "ros" not in order and re.search(r"list\(APPEND OMNICML_MODULES ros\)", text):
        order.append("ros")
    return order


def module_of(rel, modules):
    """The module a path under src/ or include/omnicml/ belongs to (longest match)."""
    best = None
    for mod in modules:
        if rel == mod or rel.startswith(mod + "/"):
            if best is None or len(mod) > len(best):
                best = mod
    return best


def main():
    root = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else pathlib.Path(__file__).parent.parent)
    order = module_order(root)
    rank = {m: i for i, m in enumerate(order)}
    include_re = re.compile(r'^\s*#\s*include\s+"omnicml/([^"]+)"')
    problems = []
    for base in (root / "src", root / "include" / "omnicml"):
        for path in sorted(base.rglob("*")):
            if path.suffix not in (".h", ".cc") or not path.is_file():
                continue
            mod = module_of(path.relative_to(base).as_posix(), order)
            if mod is None:
                problems.append(f"{path.relative_to(root)}: not in any module of OMNICML_MODULES")
                continue
            for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
                m = include_re.match(line)
                if not m:
                    continue
                other = module_of(m.group(1), order)
                if other is None:
                    problems.append(f"{path.relative_to(root)}:{n}: includes omnicml/{m.group(1)}, "
                                    "which is in no module")
                elif rank[other] > rank[mod]:
                    problems.append(f"{path.relative_to(root)}:{n}: {mod} includes {other}, "
                                    "which comes after it in the module order")
    for p in problems:
        print(p)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
