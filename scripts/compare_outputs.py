#!/usr/bin/env python3
"""Compare the outputs of `terrastride map`, `report` and `demo` for a refactoring that must not
change them.

Two output folders are equal when every file in one is in the other and
  - binary files (layers/*.npy, octomap.bt, ...) are equal byte for byte;
  - JSON files (terrain.json, plan.json, report.json, index.json, the commands' --json summaries)
    are equal after the wall-clock fields are dropped (any key containing "wall", "timings",
    "generated_utc" and the elapsed-time keys in TIMING_KEYS) and after the run's own paths are
    normalised (the output root becomes OUT, temporaries .NAME.tmp-PID-N-TICKS become .NAME.tmp);
  - report pages (*.html) are equal outside the report data they embed, and that data is equal as
    JSON by the rules above;
  - the recorded exit codes (*.rc) and messages (*.stdout, *.stderr) are equal once paths are
    normalised and durations ("0.41 s") are masked.

  compare_outputs.py --run BINARY OUT_DIR   run the standard cases with BINARY into OUT_DIR
  compare_outputs.py DIR_A DIR_B            compare two folders written by --run

Typical use: run the cases with the build before a change and with the build after it, then
compare the two folders:
  scripts/compare_outputs.py --run build-before/terrastride /tmp/before
  scripts/compare_outputs.py --run build-after/terrastride /tmp/after
  scripts/compare_outputs.py /tmp/before /tmp/after

The cases read the scans of data/scans (TERRASTRIDE_DATA_DIR, else the data folder beside this
script), which --run copies into OUT_DIR/data so both runs name the same files the same way
relative to their folder; the demo and the report need the report's assets
(TERRASTRIDE_REPORT_ASSETS_DIR, else service/report beside this script, with node_modules).

Exit status: 0 when all are equal, 1 when some differ (each difference is listed), 2 on usage
errors.
"""
import glob
import json
import os
import re
import shutil
import subprocess
import sys

# The leaf-by-leaf JSON comparison is compare_plans.py's (the same folder).
HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from compare_plans import differences  # noqa: E402


# Elapsed times (s) under other names than "wall" and "timings", and the simulation's speed
# (simulated over wall seconds).
TIMING_KEYS = {"build_s", "report_build_s", "total_s", "cpu_s", "stage_s", "load_s",
               "realtime_factor"}


def scans(pattern):
    return sorted(glob.glob(os.path.join("data", "scans", pattern)))


# name -> (arguments, run inside OUT_DIR); "{out}" is the case's output path. Every case records
# its exit code, standard output and standard error.
def cases():
    out = []
    for scene in ["pallet_10", "pallet_15", "flat", "stairs", "gap", "eur_pallet"]:
        out.append(("map_" + scene,
                    ["map"] + scans(scene + ".pcd") + scans(scene + ".[0-9].pcd") +
                    ["--out", "{out}", "--json"]))
    out += [
        # Every option away from its default, and the human-readable summary.
        ("map_pallet_15_options",
         ["map"] + scans("pallet_15*.pcd") +
         ["--resolution", "0.03", "--foot-radius", "0.03,0.07", "--octomap-resolution", "0.04",
          "--octomap-max-range", "3", "--voxel", "0.01", "--outlier-k", "10", "--outlier-stddev",
          "1.5", "--outlier-voxel", "0", "--max-step", "0.04", "--max-slope", "0.5",
          "--origin", "0,0,0.8", "--out", "{out}"]),
        ("map_pallet_10_one_cloud", ["map", "data/scans/pallet_10.pcd", "--out", "{out}"]),
        # Errors: an unreadable cloud, cleaning options the filter refuses.
        ("map_missing_cloud", ["map", "data/scans/missing.pcd", "--out", "{out}"]),
        ("map_bad_cleaning", ["map", "data/scans/flat.pcd", "--outlier-stddev", "0", "--out",
                              "{out}"]),
        # Demos (the reports below read the first one's plan): the shipped scan, and another scan
        # with other constraints and the human-readable summary.
        ("demo", ["demo", "--out", "{out}", "--json"]),
        ("demo_pallet_15", ["demo", "--scan"] + scans("pallet_15*.pcd") +
         ["--constraints", "foot", "--out", "{out}"]),
        # Reports: from clouds (mapped in the report), with options, from a map folder with a
        # plan, from a scene with a plan, and a batch over every shipped scan.
        ("report_clouds", ["report", "--terrain"] + scans("pallet_10*.pcd") +
         ["--out", "{out}/r.html", "--json"]),
        ("report_clouds_options", ["report", "--terrain"] + scans("stairs*.pcd") +
         ["--origin", "0,0,0.8", "--resolution", "0.03", "--foot-radius", "0.03,0.05",
          "--title", "stairs", "--out", "{out}/r.html"]),
        ("report_map_plan", ["report", "--terrain", "map_pallet_10", "--plan",
                             "demo/plan.json", "--out", "{out}/r.html", "--json"]),
        ("report_scene_plan", ["report", "--terrain", "pallet_10", "--plan", "demo/plan.json",
                               "--out", "{out}/r.html", "--json"]),
        ("report_batch", ["report", "--batch", "data/scans", "--out", "{out}", "--json"]),
        ("report_missing_cloud", ["report", "--terrain", "data/scans/missing.pcd", "--out",
                                  "{out}/r.html"]),
    ]
    return out


def run(binary, out_dir):
    binary = os.path.abspath(binary)
    os.makedirs(out_dir, exist_ok=True)
    data = os.environ.get("TERRASTRIDE_DATA_DIR") or os.path.join(HERE, "..", "data")
    if not os.path.isdir(os.path.join(out_dir, "data")):
        shutil.copytree(data, os.path.join(out_dir, "data"))
    env = dict(os.environ)
    env["TERRASTRIDE_DATA_DIR"] = os.path.abspath(os.path.join(out_dir, "data"))
    env.setdefault("TERRASTRIDE_REPORT_ASSETS_DIR", os.path.join(HERE, "..", "service", "report"))
    os.chdir(out_dir)
    for name, args in cases():
        args = [a.replace("{out}", name) for a in args]
        if name.startswith("report") and not name.endswith("batch"):
            os.makedirs(name, exist_ok=True)
        res = subprocess.run([binary] + args, env=env, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
        print("%-26s exit %d" % (name, res.returncode))
        for ext, text in (("rc", "%d\n" % res.returncode), ("stdout", res.stdout),
                          ("stderr", res.stderr)):
            with open(name + "." + ext, "w") as f:
                f.write(text)
    return True


def normalise_text(text, root):
    text = text.replace(os.path.realpath(root), "OUT").replace(os.path.abspath(root), "OUT")
    text = re.sub(r"(\.[^/\s\"]+)\.tmp-\d+-\d+-\d+", r"\1.tmp", text)
    return text


def strip(node, root):
    if isinstance(node, dict):
        return {k: strip(v, root) for k, v in node.items()
                if not ("wall" in k or k in ("timings", "generated_utc") or k in TIMING_KEYS)}
    if isinstance(node, list):
        return [strip(v, root) for v in node]
    if isinstance(node, str):
        return mask_solver_time(normalise_text(node, root))
    return node


def report_differences(what, a, b):
    diffs = differences(a, b)
    if not diffs:
        return True
    print("DIFFERENT  %s: %d values differ" % (what, len(diffs)))
    for path, x, y in diffs[:10]:
        print("    %s: %.200r -> %.200r" % (path, x, y))
    if len(diffs) > 10:
        print("    ... and %d more" % (len(diffs) - 10))
    return False


def json_lines(text):
    """A command's --json output: one JSON document per line (other lines kept as text)."""
    out = []
    for line in text.splitlines():
        try:
            out.append(json.loads(line))
        except ValueError:
            out.append(line)
    return out


def split_html(text):
    """(page without the embedded report data, the data) for a report or index page."""
    for marker in ("window.REPORT = ", "window.INDEX = "):
        at = text.find(marker)
        if at >= 0:
            at += len(marker)
            break
    else:
        return text, None
    # The page's script escapes "</" as "<\/", which JSON reads back as "</".
    try:
        data, end = json.JSONDecoder().raw_decode(text, at)
    except ValueError:
        return text, None
    return text[:at] + "DATA" + text[end:], data


def mask_durations(text):
    text = re.sub(r"\d+(\.\d+)?x real time", "Nx real time", text)
    return re.sub(r"\d+(\.\d+)? s\b", "N s", text)


# The solver's wall time in the report's summary notes ("11 iterations, 2.925 s, ...").
def mask_solver_time(text):
    return re.sub(r"iterations, \d+\.\d+ s,", "iterations, N s,", text)


def compare_file(path_a, path_b, root_a, root_b, rel):
    with open(path_a, "rb") as f:
        bytes_a = f.read()
    with open(path_b, "rb") as f:
        bytes_b = f.read()
    if rel.endswith(".json") or rel.endswith(".stdout") or rel.endswith(".stderr"):
        text_a = bytes_a.decode()
        text_b = bytes_b.decode()
        if rel.endswith(".json"):
            a, b = json.loads(text_a), json.loads(text_b)
        else:
            a = [mask_durations(x) if isinstance(x, str) else x for x in json_lines(text_a)]
            b = [mask_durations(x) if isinstance(x, str) else x for x in json_lines(text_b)]
        return report_differences(rel, strip(a, root_a), strip(b, root_b))
    if rel.endswith(".html"):
        page_a, data_a = split_html(bytes_a.decode())
        page_b, data_b = split_html(bytes_b.decode())
        if page_a != page_b:
            print("DIFFERENT  %s: the page outside its data differs" % rel)
            return False
        return report_differences(rel + " (data)", strip(data_a, root_a), strip(data_b, root_b))
    if rel.endswith(".terrastride-output") or rel.endswith(".rc"):
        if normalise_text(bytes_a.decode(), root_a) == normalise_text(bytes_b.decode(), root_b):
            return True
    elif bytes_a == bytes_b:
        return True
    print("DIFFERENT  %s: %d bytes -> %d bytes" % (rel, len(bytes_a), len(bytes_b)))
    return False


def files_under(root):
    out = set()
    for dirpath, _, names in os.walk(root):
        rel_dir = os.path.relpath(dirpath, root)
        if rel_dir == "data" or rel_dir.startswith("data" + os.sep):
            continue
        for n in names:
            out.add(os.path.normpath(os.path.join(rel_dir, n)))
    return out


def compare_dirs(dir_a, dir_b):
    files_a, files_b = files_under(dir_a), files_under(dir_b)
    ok = True
    for rel in sorted(files_a ^ files_b):
        print("MISSING    %s in %s" % (rel, dir_b if rel in files_a else dir_a))
        ok = False
    same = sorted(files_a & files_b)
    for rel in same:
        ok = compare_file(os.path.join(dir_a, rel), os.path.join(dir_b, rel), dir_a, dir_b,
                          rel) and ok
    print("all %d files identical" % len(same) if ok else "outputs differ")
    return ok


def main(argv):
    if len(argv) == 4 and argv[1] == "--run":
        return 0 if run(argv[2], argv[3]) else 1
    if len(argv) != 3 or not (os.path.isdir(argv[1]) and os.path.isdir(argv[2])):
        print(__doc__)
        return 2
    return 0 if compare_dirs(argv[1], argv[2]) else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv))
