#!/usr/bin/env python3
"""Quality figures of plan.json files (as planner/quality.hpp computes them), for
plans written before the "quality" block existed and as an independent check of it.
usage: scripts/plan_quality.py PLAN.json [PLAN.json ...]"""
import json
import math
import sys


def quality(plan):
    S = plan["samples"]
    pos = [s["base"]["position"] for s in S]
    p0, p1 = pos[0], pos[-1]
    dx, dy = p1[0] - p0[0], p1[1] - p0[1]
    straight = math.hypot(dx, dy)
    length = sum(math.hypot(b[0] - a[0], b[1] - a[1]) for a, b in zip(pos, pos[1:]))
    q = {"path_ratio": length / straight if straight > 0.01 else None}
    back = sway = 0.0
    if straight > 0.01:
        ax, ay = dx / straight, dy / straight
        furthest = 0.0
        for p in pos:
            prog = ax * (p[0] - p0[0]) + ay * (p[1] - p0[1])
            furthest = max(furthest, prog)
            back = max(back, furthest - prog)
            sway = max(sway, abs(-ay * (p[0] - p0[0]) + ax * (p[1] - p0[1])))
    q["backward_max_m"], q["lateral_sway_m"] = back, sway
    step = 0.0
    for a, b in zip(S, S[1:]):
        dt = b["t"] - a["t"]
        for fa, fb in zip(a["feet"], b["feet"]):
            va = fa["force"] if fa["contact"] else [0, 0, 0]
            vb = fb["force"] if fb["contact"] else [0, 0, 0]
            step = max(step, math.dist(va, vb) * 0.01 / dt)
    q["force_step_max_N_per_10ms"] = step
    q["start_acceleration_m_s2"] = math.hypot(*S[0]["base"]["linear_acceleration"])
    q["end_acceleration_m_s2"] = math.hypot(*S[-1]["base"]["linear_acceleration"])
    rise = 0.0
    for f in range(len(S[0]["feet"])):
        k = 1
        while k < len(S):
            if S[k - 1]["feet"][f]["contact"] and not S[k]["feet"][f]["contact"]:
                j, top = k, -1e9
                while j < len(S) and not S[j]["feet"][f]["contact"]:
                    top = max(top, S[j]["feet"][f]["position"][2])
                    j += 1
                if j == len(S):
                    break
                ends = max(S[k - 1]["feet"][f]["position"][2], S[j]["feet"][f]["position"][2])
                rise = max(rise, top - ends)
                k = j + 1
            else:
                k += 1
    q["swing_rise_max_m"] = rise
    return q


for path in sys.argv[1:]:
    with open(path) as fh:
        plan = json.load(fh)
    q = quality(plan)
    solver = plan.get("solver", {})
    print(path, "iterations", solver.get("iterations"), "status", solver.get("status"),
          " ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in q.items()),
          "energy_proxy_J", plan.get("checks", {}).get("energy_proxy_J"))
