#!/usr/bin/env bash
# Streaming a bag of at least 1 GB: writes one in a scratch folder with the fixture
# generator's big_bag.mjs (MCAP, zstd chunks of 4 MB, 64 x 1024 organised clouds at 10 Hz, /tf at
# 50 Hz), then measures `map --list` (every message read, headers decoded) and `map --every N`
# (every N-th cloud placed and mapped) with /usr/bin/time: wall time and peak RSS.
#   tests/bench/bench_bag_stream.sh [build/terrastride] [GB=1.05] [EVERY=10] [SPEED=0.5] [MAP FLAGS...]
# SPEED is the base's speed in m/s (0: a sensor standing still, the ground seen again and again);
# MAP FLAGS go to `map`, e.g. --max-cell-points 0.
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
bin=${1:-$root/build/terrastride}
gb=${2:-1.05}
every=${3:-10}
speed=${4:-0.5}
shift $(( $# < 4 ? $# : 4 ))
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
gen=$root/tests/fixtures/bags/generator
[ -d "$gen/node_modules" ] || npm ci --prefix "$gen" --no-audit --no-fund --loglevel=error
node "$gen/big_bag.mjs" "$scratch/big.mcap" "$gb" zstd "$speed"
ls -l "$scratch/big.mcap"
uptime
/usr/bin/time -f "list: %e s wall, %M KB peak RSS" "$bin" map "$scratch/big.mcap" --list >/dev/null
/usr/bin/time -f "map --every $every: %e s wall, %M KB peak RSS" "$bin" map "$scratch/big.mcap" \
  --topic /points --frame odom --every "$every" --out "$scratch/map" --json "$@" >"$scratch/summary.json"
python3 -c "import json,sys; s=json.load(open(sys.argv[1])); b=s['bags'][0]; t=b['topics']['/points']; \
print('clouds used', t['used'], 'of', t['messages'], '; points', t['points_in'], '; non-finite', t['non_finite']); \
print('timings', s['timings']); print('stream', b.get('stream')); print('points kept', s['points_kept'])" "$scratch/summary.json"
