#!/usr/bin/python3
"""Seeds for fuzz_plan (corpus_plan/): plan.json documents in the format plan_to_json writes
(docs/design.md, plan.json), written here with the standard library only: a minimal plan, one
carrying a shipped robot's definition (robot_file with its FNV-1a hash, so robot_of_plan parses
the YAML), and the hostile ones: extra keys nested beyond the parser's cap, integers wider than
an int, times that do not increase, non-finite numbers written as null, huge and negative sizes.
Usage: /usr/bin/python3 tests/fuzz/make_plan_seeds.py"""
import copy
import json
import os

here = os.path.dirname(os.path.abspath(__file__))
out = os.path.join(here, "corpus_plan")
robots = os.path.join(here, "..", "..", "data", "robots")
os.makedirs(out, exist_ok=True)


def write(name, text):
    with open(os.path.join(out, name), "w") as f:
        f.write(text)


def fnv1a(text):
    h = 1469598103934665603
    for b in text.encode():
        h = ((h ^ b) * 1099511628211) % (1 << 64)
    return "%016x" % h


def sample(t, feet):
    foot = {"position": [0.3, 0.2, 0.0], "velocity": [0, 0, 0], "force": [0, 0, 50.0],
            "contact": True}
    return {"t": t,
            "base": {"position": [0.01 * t, 0, 0.5], "euler_zyx": [0, 0, 0],
                     "linear_velocity": [0, 0, 0], "angular_velocity": [0, 0, 0],
                     "linear_acceleration": [0, 0, 0], "angular_acceleration": [0, 0, 0]},
            "feet": [foot] * len(feet)}


feet = ["LF", "RF", "LH", "RH"]
plan = {"robot": "hyq", "gait": "crawl", "duration": 0.02, "sample_dt": 0.01, "feet": feet,
        "samples": [sample(0.01 * k, feet) for k in range(3)],
        "solver": {"status": "optimal", "iterations": 12, "wall_s": 0.5, "n_variables": 100,
                   "n_constraints": 90},
        "checks": {"dynamics_linear_max_N": 1.5}, "phases": {"LF": [[0.0, 0.02]]}}
write("minimal.json", json.dumps(plan))

with open(os.path.join(robots, "go2.yaml")) as f:
    go2 = f.read()
carried = copy.deepcopy(plan)
carried["robot"] = "go2"
carried["robot_file"] = {"hash": fnv1a(go2), "yaml": go2}
write("robot_file.json", json.dumps(carried))
altered = copy.deepcopy(carried)
altered["robot_file"]["yaml"] = go2.replace("go2", "go3")
altered["robot_file"]["hash"] = fnv1a(altered["robot_file"]["yaml"])
write("robot_file_renamed.json", json.dumps(altered))
write("robot_file_not_yaml.json",
      json.dumps(dict(carried, robot_file={"hash": fnv1a("[: {"), "yaml": "[: {"})))

text = json.dumps(plan)
write("nested_beyond_cap.json", text[:-1] + ', "notes": ' + "[" * 5000 + "]" * 5000 + "}")
write("nested_at_cap.json", text[:-1] + ', "notes": ' + "[" * 99 + "]" * 99 + "}")
wide = copy.deepcopy(plan)
wide["solver"]["iterations"] = 4294967297
write("iterations_wider_than_int.json", json.dumps(wide))
wide["solver"]["n_variables"] = -3000000000
write("variables_below_int.json", json.dumps(wide))
back = copy.deepcopy(plan)
back["samples"][2]["t"] = 0.0
write("times_back.json", json.dumps(back))
null = copy.deepcopy(plan)
null["samples"][1]["feet"][0]["force"][2] = None
write("force_null.json", json.dumps(null))
huge = copy.deepcopy(plan)
huge["duration"] = 1e308
huge["sample_dt"] = 5e-324
huge["samples"][2]["t"] = 1e308
write("huge_times.json", json.dumps(huge))
write("number_beyond_double.json", text.replace('"duration": 0.02', '"duration": 1e999'))
