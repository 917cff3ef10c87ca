#!/usr/bin/env bash
# Builds the protocol fuzz target with clang and runs it briefly on the seed corpus.
# Usage: tests/fuzz/run.sh [SECONDS] (default 30). Findings land in build-fuzz/artifacts/.
set -euo pipefail
cd "$(dirname "$0")/../.."
seconds="${1:-30}"
CC=clang CXX=clang++ cmake -S tests/fuzz -B build-fuzz -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
cmake --build build-fuzz >/dev/null
mkdir -p build-fuzz/corpus build-fuzz/artifacts
# New inputs go to build-fuzz/corpus; the seed corpus in the tree is read only.
build-fuzz/fuzz_protocol -max_total_time="$seconds" -max_len=65536 -timeout=10 -rss_limit_mb=2048 \
  -artifact_prefix=build-fuzz/artifacts/ build-fuzz/corpus tests/fuzz/corpus
