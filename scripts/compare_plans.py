#!/usr/bin/env python3
"""Compare plan.json files for a refactoring that must not change behaviour.

Two plans are equal when their JSON documents are equal after the wall-clock fields are dropped
(any key containing "wall", e.g. solver.wall_s and post_hoc.wall_s, and the "timings" object): the
same iterations, the same samples to the last bit, the same checks. Numbers are compared as the
doubles they were written as (json.dumps(sort_keys=True) of both documents).

  compare_plans.py A.json B.json           compare two plans
  compare_plans.py DIR_A DIR_B             compare every *.json of DIR_A with its namesake in DIR_B
  compare_plans.py --run BINARY OUT_DIR    plan the standard scenarios with BINARY into OUT_DIR

Typical use: plan the scenarios with the build before a change and with the build after it, then
compare the two folders:
  scripts/compare_plans.py --run build-before/terrastride /tmp/before
  scripts/compare_plans.py --run build-after/terrastride /tmp/after
  scripts/compare_plans.py /tmp/before /tmp/after

Exit status: 0 when all are equal, 1 when some differ (each difference is listed: its path in the
document, both values and, for numbers, the difference), 2 on usage errors.
"""
import json
import math
import os
import subprocess
import sys

# name -> arguments of `terrastride plan` (the --out is added). The ten-scenario benchmark's scenes
# and variants (tests/bench/bench_scenarios.cpp) through the command line, a re-plan and the monoped.
SCENARIOS = [
    ("flat_2.4s", ["--terrain", "flat", "--duration", "2.4"]),
    ("flat_2.4s_all", ["--terrain", "flat", "--duration", "2.4", "--constraints", "all"]),
    ("flat_2.4s_timing", ["--terrain", "flat", "--duration", "2.4", "--optimize-timing"]),
    ("pallet_10", ["--terrain", "pallet_10"]),
    ("pallet_15", ["--terrain", "pallet_15"]),
    ("pallet_15_all", ["--terrain", "pallet_15", "--constraints", "all"]),
    ("pallet_15_timing", ["--terrain", "pallet_15", "--optimize-timing"]),
    ("pallet_15_shin", ["--terrain", "pallet_15", "--constraints", "foot,shin"]),
    ("stairs", ["--terrain", "stairs"]),
    ("eur_pallet_all", ["--terrain", "eur_pallet", "--constraints", "all"]),
    ("gap", ["--terrain", "gap"]),
    ("flat_trot", ["--terrain", "flat", "--gait", "trot"]),
    ("monoped_hop", ["--terrain", "flat", "--robot", "monoped", "--gait", "hop"]),
    # Re-plans of pallet_15 (its plan must come first): from the plan's own state, and from a
    # measured state beside it.
    ("pallet_15_warm_0.1s", ["--terrain", "pallet_15", "--init", "pallet_15.json",
                             "--start-time", "0.1"]),
    ("pallet_15_warm_1s_state", ["--terrain", "pallet_15", "--init", "pallet_15.json",
                                 "--start-time", "1.0", "--start-state", "measured_state.json"]),
]
# The measured state of pallet_15_warm_1s_state: the base 1 cm to the side of the plan.
MEASURED_STATE = {"base": {"position": [0.10, 0.01, 0.56]}}


def is_wall_clock(key):
    return "wall" in key or key == "timings"


def strip(node):
    if isinstance(node, dict):
        return {k: strip(v) for k, v in node.items() if not is_wall_clock(k)}
    if isinstance(node, list):
        return [strip(v) for v in node]
    return node


def differences(a, b, path=""):
    """(path, value a, value b) for every leaf that differs."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                out.append((path + "/" + k, a.get(k, "<absent>"), b.get(k, "<absent>")))
            else:
                out += differences(a[k], b[k], path + "/" + k)
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [(path, "length %d" % len(a), "length %d" % len(b))]
        out = []
        for i, (x, y) in enumerate(zip(a, b)):
            out += differences(x, y, "%s[%d]" % (path, i))
        return out
    if a != b or type(a) != type(b):
        return [(path, a, b)]
    return []


def load(path):
    with open(path) as f:
        return strip(json.load(f))


def compare_files(path_a, path_b, quiet=False):
    a, b = load(path_a), load(path_b)
    iterations = (a.get("solver", {}).get("iterations"), b.get("solver", {}).get("iterations"))
    if json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True):
        if not quiet:
            print("identical  %s (iterations %s)" % (os.path.basename(path_b), iterations[1]))
        return True
    diffs = differences(a, b)
    largest = 0.0
    for _, x, y in diffs:
        if isinstance(x, (int, float)) and isinstance(y, (int, float)):
            largest = max(largest, abs(x - y))
    print("DIFFERENT  %s: %d values differ, largest numeric difference %g, iterations %s -> %s"
          % (os.path.basename(path_b), len(diffs), largest, iterations[0], iterations[1]))
    for path, x, y in diffs[:20]:
        extra = ""
        if isinstance(x, (int, float)) and isinstance(y, (int, float)) and not isinstance(x, bool):
            extra = "  (difference %g)" % (y - x) if math.isfinite(y - x) else ""
        print("    %s: %r -> %r%s" % (path, x, y, extra))
    if len(diffs) > 20:
        print("    ... and %d more" % (len(diffs) - 20))
    return False


def compare_dirs(dir_a, dir_b):
    names = sorted(n for n in os.listdir(dir_a) if n.endswith(".json") and n != "measured_state.json")
    if not names:
        print("no plan files in " + dir_a)
        return False
    ok = True
    for n in names:
        if not os.path.exists(os.path.join(dir_b, n)):
            print("MISSING    %s in %s" % (n, dir_b))
            ok = False
            continue
        ok = compare_files(os.path.join(dir_a, n), os.path.join(dir_b, n)) and ok
    print("all %d plans identical" % len(names) if ok else "plans differ")
    return ok


def run(binary, out_dir):
    # Plans run inside out_dir and name their files relative to it, so that the paths a re-plan
    # records (its "init" and "start_state") are the same in every folder.
    binary = os.path.abspath(binary)
    os.makedirs(out_dir, exist_ok=True)
    with open(os.path.join(out_dir, "measured_state.json"), "w") as f:
        json.dump(MEASURED_STATE, f)
    failed = False
    for name, args in SCENARIOS:
        out = name + ".json"
        cmd = [binary, "plan"] + args + ["--out", out]
        res = subprocess.run(cmd, cwd=out_dir, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                             text=True)
        first = res.stdout.splitlines()[0] if res.stdout else ""
        print("%-26s exit %d  %s" % (name, res.returncode, first))
        # An unsuccessful solve still writes its plan (exit 1); anything else is a failure.
        if not os.path.exists(os.path.join(out_dir, out)):
            print(res.stdout)
            failed = True
    return not failed


def main(argv):
    if len(argv) == 4 and argv[1] == "--run":
        return 0 if run(argv[2], argv[3]) else 1
    if len(argv) != 3:
        print(__doc__)
        return 2
    a, b = argv[1], argv[2]
    if os.path.isdir(a) and os.path.isdir(b):
        return 0 if compare_dirs(a, b) else 1
    if os.path.isfile(a) and os.path.isfile(b):
        return 0 if compare_files(a, b) else 1
    print("both arguments must be plan files or both folders")
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv))
