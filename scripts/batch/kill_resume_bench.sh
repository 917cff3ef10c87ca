#!/bin/bash
# The kill test at full size: a `report --batch` over 20 scans killed (SIGKILL) at random
# moments and resumed, TRIALS times, each compared byte for byte (diff -r, hidden files included)
# with one uninterrupted run; then 4 shards at once over one folder against the same run.
# The fast version of both is tests/service/test_report_batch.cpp.
#   bash scripts/batch/kill_resume_bench.sh [build/terrastride] [TRIALS=5] [KILLS_PER_TRIAL=3]
set -u
T=$(realpath "${1:-build/terrastride}")
TRIALS=${2:-5}
KILLS=${3:-3}
WORK=$(mktemp -d /tmp/terrastride-batch-bench.XXXXXX)
trap 'rm -rf "$WORK"' EXIT
cd "$WORK" || exit 1
mkdir scans
# 20 scans: the six scenes scanned from 3-4 sensor seeds each (one pose per scan).
n=0
for seed in 1 2 3 4; do
  for scene in flat pallet_10 pallet_15 eur_pallet stairs gap; do
    [ $n -ge 20 ] && break
    "$T" scan-sim --scene "$scene" --out "scans/${scene}_s${seed}.pcd" --poses 1 --seed "$seed" \
      >/dev/null 2>&1 || { echo "scan-sim $scene failed"; exit 1; }
    n=$((n + 1))
  done
done
echo "scans: $(ls scans | wc -l)   load: $(uptime | sed 's/.*load average: //')"
now() { date +%s.%N; }
t0=$(now)
"$T" report --batch scans --out reference >/dev/null 2>&1
echo "uninterrupted run: exit $?, $(echo "$(now) - $t0" | bc) s"
full=$(echo "$(now) - $t0" | bc)
RANDOM=21
identical=0
for trial in $(seq 1 "$TRIALS"); do
  out="trial$trial"
  kills=""
  for k in $(seq 1 "$KILLS"); do
    "$T" report --batch scans --out "$out" --resume >/dev/null 2>&1 &
    pid=$!
    # Uniform in (0, full/KILLS): each run is resumed work, so the later ones are shorter.
    delay=$(echo "scale=3; $full * $RANDOM / 32768 / $KILLS" | bc)
    sleep "$delay"
    if kill -9 "$pid" 2>/dev/null; then kills="$kills ${delay}s"; else kills="$kills (finished before ${delay}s)"; fi
    wait "$pid" 2>/dev/null
    done_now=$(find "$out" -mindepth 2 -maxdepth 2 -name summary.json 2>/dev/null | wc -l)
    kills="$kills[$done_now scans]"
  done
  "$T" report --batch scans --out "$out" --resume >/dev/null 2>&1
  code=$?
  if diff -r reference "$out" >/dev/null; then verdict=identical; identical=$((identical + 1)); else verdict=DIFFERENT; fi
  echo "trial $trial: killed at$kills; resume exit $code; $verdict ($(find "$out" -type f | wc -l) files)"
done
t0=$(now)
for i in 0 1 2 3; do "$T" report --batch scans --out four --shard $i/4 >/dev/null 2>&1 & done
wait
four_s=$(echo "$(now) - $t0" | bc)
if diff -r reference four >/dev/null; then v=identical; else v=DIFFERENT; fi
echo "4 shards at once: $v to one process ($four_s s wall vs $full s)"
echo "summary: $identical of $TRIALS resumed trials identical; 4 shards $v"
[ "$identical" -eq "$TRIALS" ] && [ "$v" = identical ]
