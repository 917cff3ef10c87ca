#!/usr/bin/env bash
# Builds the fuzz targets with clang and runs each briefly on its seed corpus: fuzz_protocol (the
# wire protocol; seeds tests/fuzz/corpus) and fuzz_bag (the MCAP/.db3 readers, CDR and ROS 1
# PointCloud2/TFMessage decoding, the tf buffer; seeds
# tests/fuzz/corpus_bag).
# Usage: tests/fuzz/run.sh [SECONDS] (default 30): the whole fuzzing budget, split evenly between
# the targets, so CI's `tests/fuzz/run.sh 30` still fuzzes for 30 s in all. Findings land in
# build-fuzz/artifacts/; the script fails when a target does.
set -euo pipefail
cd "$(dirname "$0")/../.."
seconds="${1:-30}"
per_target=$(( seconds / 2 > 0 ? seconds / 2 : 1 ))
CC=clang CXX=clang++ cmake -S tests/fuzz -B build-fuzz -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
cmake --build build-fuzz >/dev/null
mkdir -p build-fuzz/corpus build-fuzz/corpus_bag build-fuzz/artifacts build-fuzz/tmp
# New inputs go to build-fuzz/corpus*; the seed corpora in the tree are read only.
build-fuzz/fuzz_protocol -max_total_time="$per_target" -max_len=65536 -timeout=10 -rss_limit_mb=2048 \
  -artifact_prefix=build-fuzz/artifacts/ build-fuzz/corpus tests/fuzz/corpus
# Small seeds (tiny MCAPs, a tiny .db3, single messages): the full fixtures (100-220 kB) ran at
# about 24 inputs/s under ASan, too few for a 15 s share. fuzz_bag writes each input to a scratch
# file under $TMPDIR.
TMPDIR="$PWD/build-fuzz/tmp" build-fuzz/fuzz_bag -max_total_time="$per_target" -max_len=16384 \
  -timeout=10 -rss_limit_mb=2048 -artifact_prefix=build-fuzz/artifacts/bag- \
  build-fuzz/corpus_bag tests/fuzz/corpus_bag
