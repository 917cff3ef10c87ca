#!/usr/bin/env python3
"""How far a closed loop's base strays from its reference plan's posture.

Reads two `terrastride simulate --out` files of the same plan: a closed loop (`--replan-every`)
and the open loop, whose `planned_base` is the reference plan. At every sample time both hold,
it compares the closed loop's actual base with the reference's: roll (largest and RMS deviation,
rad) and lateral position y (largest deviation, m). The closed loop's own plan is printed beside
it (largest roll deviation of the actual base from the plan it tracked), to tell drift of the
plans from tracking error.

  posture_drift.py CLOSED.json OPEN.json

Example (pallet_15 `all`):
  build/terrastride plan --terrain pallet_15 --constraints all --gait crawl --cycles 3 \
      --duration 11 --out p15.json
  build/terrastride simulate p15.json --terrain pallet_15 --out open.json
  build/terrastride simulate p15.json --terrain pallet_15 --replan-every 0.1 --horizon 1 \
      --out closed.json
  scripts/posture_drift.py closed.json open.json
Exit status: 0, or 2 on usage errors (wrong arguments, files without samples).
"""
import json
import math
import sys


def samples_by_time(path):
    with open(path) as f:
        doc = json.load(f)
    samples = doc.get("samples")
    if not isinstance(samples, list) or not samples:
        raise ValueError(f"{path}: no 'samples' (write it with 'terrastride simulate --out')")
    return {round(s["t"], 4): s for s in samples}


def main(argv):
    if len(argv) != 3:
        print(__doc__.strip().splitlines()[0], file=sys.stderr)
        print("usage: posture_drift.py CLOSED.json OPEN.json", file=sys.stderr)
        return 2
    try:
        closed, opened = samples_by_time(argv[1]), samples_by_time(argv[2])
    except (OSError, ValueError, KeyError, json.JSONDecodeError) as e:
        print(f"posture_drift.py: {e}", file=sys.stderr)
        return 2
    roll_max = roll_sq = y_max = tracking_max = 0.0
    n = 0
    for t, s in closed.items():
        if t not in opened:
            continue
        reference = opened[t]["planned_base"]
        roll = s["base"]["euler_zyx"][2]
        d_roll = abs(roll - reference["euler_zyx"][2])
        roll_max = max(roll_max, d_roll)
        roll_sq += d_roll * d_roll
        y_max = max(y_max, abs(s["base"]["position"][1] - reference["position"][1]))
        tracking_max = max(tracking_max, abs(roll - s["planned_base"]["euler_zyx"][2]))
        n += 1
    if n == 0:
        print("posture_drift.py: the two runs share no sample time", file=sys.stderr)
        return 2
    print(f"{n} samples: roll off the reference max {roll_max:.3f} rad, RMS "
          f"{math.sqrt(roll_sq / n):.3f} rad; y off it max {y_max:.3f} m; "
          f"roll off the tracked plan max {tracking_max:.3f} rad")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
