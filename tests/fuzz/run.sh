#!/usr/bin/env bash
# Builds the fuzz targets with clang and runs each briefly on its seed corpus: fuzz_protocol (the
# wire protocol; seeds tests/fuzz/corpus), fuzz_bag (the MCAP/.db3 readers, the ROS 1 bag check,
# CDR and ROS 1 PointCloud2/TFMessage decoding, the tf buffer; seeds tests/fuzz/corpus_bag),
# fuzz_files (OctoMap .bt/.ot, PCD and PLY checks, NPY; seeds tests/fuzz/corpus_files),
# fuzz_urdf (the URDF import; seeds tests/fuzz/corpus_urdf) and fuzz_plan (plan.json and the
# robot definition it carries; seeds tests/fuzz/corpus_plan).
# Usage: tests/fuzz/run.sh [SECONDS] (default 60): the whole fuzzing budget, split evenly between
# the targets, so CI's `tests/fuzz/run.sh 60` fuzzes for 60 s in all. Findings land in
# build-fuzz/artifacts/; the script fails when a target does.
set -euo pipefail
cd "$(dirname "$0")/../.."
seconds="${1:-60}"
# target, seed corpus, max input length. A new target is one more line here (and in
# CMakeLists.txt); the budget is shared.
targets=(
  "fuzz_protocol corpus 65536"
  "fuzz_bag corpus_bag 16384"
  "fuzz_files corpus_files 16384"
  "fuzz_urdf corpus_urdf 65536"
  "fuzz_plan corpus_plan 16384"
)
per_target=$(( seconds / ${#targets[@]} > 0 ? seconds / ${#targets[@]} : 1 ))
CC=clang CXX=clang++ cmake -S tests/fuzz -B build-fuzz -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
# The build's log is kept and shown when it fails: a link error must not end CI silently.
mkdir -p build-fuzz
cmake --build build-fuzz >build-fuzz/build.log 2>&1 || { tail -n 60 build-fuzz/build.log >&2; exit 1; }
mkdir -p build-fuzz/artifacts build-fuzz/tmp
for entry in "${targets[@]}"; do
  read -r target corpus max_len <<<"$entry"
  mkdir -p "build-fuzz/$corpus"
  # New inputs go to build-fuzz/CORPUS; the seed corpora in the tree are read only. Small seeds:
  # the full bag fixtures (100-220 kB) ran at about 24 inputs/s under ASan, too few for a share.
  # The file targets write each input to a scratch file under $TMPDIR.
  TMPDIR="$PWD/build-fuzz/tmp" "build-fuzz/$target" -max_total_time="$per_target" \
    -max_len="$max_len" -timeout=10 -rss_limit_mb=2048 \
    -artifact_prefix="build-fuzz/artifacts/$target-" "build-fuzz/$corpus" "tests/fuzz/$corpus"
done
