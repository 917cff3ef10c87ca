#!/usr/bin/env python3
"""House rules of the repository, checked in CI (.ci/run):

1. No product function longer than 120 lines (perception/ terrain/ planner/ collision/ service/;
   measured with universal-ctags, which gives every C++ function's first and last line).
2. No reference to the history of the work in tracked files: "session N", "issue #N", "(#N)".
   The design and the code describe what the product does now; history belongs in commit messages.

The functions and files that broke a rule when the rule was introduced are listed in
scripts/house_baseline.json with their figure then: they may shrink, never grow, and nothing new may
join them. `--write-baseline` rewrites that file from the tree (only to record an improvement:
review its diff). Exit 0 when the tree keeps the rules, 1 when it breaks one (each named), 2 when
ctags is missing.
"""
import argparse
import json
import os
import re
import shutil
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BASELINE = os.path.join(ROOT, "scripts", "house_baseline.json")
PRODUCT_DIRS = ["perception", "terrain", "planner", "collision", "simulation", "service"]
MAX_FUNCTION_LINES = 120
HISTORY = re.compile(r"\b[Ss]ession \d+\b|\b[Ii]ssues? ?#\d+|\(#\d+(?:, ?#\d+)*\)")
# Files the history rule does not read: binary data, vendored assets, and this script's own
# baseline (it names the offenders).
HISTORY_SKIP = re.compile(r"(^|/)(node_modules|corpus[^/]*)/|\.(png|jpg|pcd|ply|npy|bt|ot|bag|mcap|db3|"
                          r"bin|gz|zst)$|^scripts/house_baseline\.json$|^scripts/check_house\.py$")


def long_functions():
    """{"path:name@scope": lines} of product functions over the limit."""
    if not shutil.which("ctags"):
        print("check_house: universal-ctags is not installed (apt-get install universal-ctags)",
              file=sys.stderr)
        sys.exit(2)
    out = subprocess.run(
        ["ctags", "--output-format=json", "--fields=+ne", "--kinds-C++=f", "--languages=C++",
         "--exclude=node_modules", "-R"] + PRODUCT_DIRS,
        cwd=ROOT, check=True, capture_output=True, text=True).stdout
    found = {}
    for line in out.splitlines():
        tag = json.loads(line)
        if tag.get("kind") != "function" or "end" not in tag or tag["name"].startswith("__anon"):
            continue
        lines = tag["end"] - tag["line"] + 1
        if lines > MAX_FUNCTION_LINES:
            scope = re.sub(r"__anon\w+", "", tag.get("scope", "")).replace("::::", "::").strip(":")
            key = f"{tag['path']}:{scope + '::' if scope else ''}{tag['name']}"
            found[key] = max(lines, found.get(key, 0))
    return found


def history_references():
    """{"path": count} of references to the history of the work in tracked text files."""
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, check=True, capture_output=True,
                           text=True).stdout.split("\n")
    found = {}
    for path in files:
        if not path or HISTORY_SKIP.search(path):
            continue
        try:
            with open(os.path.join(ROOT, path), encoding="utf-8") as f:
                text = f.read()
        except (UnicodeDecodeError, FileNotFoundError, IsADirectoryError):
            continue
        n = len(HISTORY.findall(text))
        if n:
            found[path] = n
    return found


def compare(kind, now, baseline, unit):
    """Names what is new or grew against the baseline; returns the number of breaches."""
    breaches = 0
    for key, value in sorted(now.items()):
        allowed = baseline.get(key)
        if allowed is None:
            print(f"check_house: {kind}: {key}: {value} {unit} (new; the limit is "
                  f"{MAX_FUNCTION_LINES if kind == 'long function' else 0})")
            breaches += 1
        elif value > allowed:
            print(f"check_house: {kind}: {key}: {value} {unit}, more than the {allowed} it had")
            breaches += 1
    return breaches


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--write-baseline", action="store_true",
                        help="record the tree's figures as the baseline")
    args = parser.parse_args()
    functions, references = long_functions(), history_references()
    if args.write_baseline:
        with open(BASELINE, "w", encoding="utf-8") as f:
            json.dump({"long_functions": functions, "history_references": references}, f,
                      indent=1, sort_keys=True)
            f.write("\n")
        print(f"check_house: wrote {os.path.relpath(BASELINE, ROOT)}")
        return 0
    with open(BASELINE, encoding="utf-8") as f:
        baseline = json.load(f)
    breaches = compare("long function", functions, baseline["long_functions"], "lines")
    breaches += compare("history reference", references, baseline["history_references"],
                        "references")
    print(f"check_house: {len(functions)} product functions over {MAX_FUNCTION_LINES} lines "
          f"(baseline {len(baseline['long_functions'])}), "
          f"{sum(references.values())} history references in {len(references)} files "
          f"(baseline {sum(baseline['history_references'].values())}); "
          f"{breaches} breach{'es' if breaches != 1 else ''}")
    return 1 if breaches else 0


if __name__ == "__main__":
    sys.exit(main())
