#!/usr/bin/env python3
"""Example: load a scene, query footholds, push a scan, ask for a plan.

    terrastride serve --listen tcp://127.0.0.1:7700 &
    python3 service/clients/python/example.py tcp://127.0.0.1:7700
"""
import sys

from terrastride_client import Attachment, Client, ServiceError

address = sys.argv[1] if len(sys.argv) > 1 else "tcp://127.0.0.1:7700"
with Client.connect(address) as c:
    hello = c.call("hello")
    print(f"server {hello['version']} protocol {hello['protocol']}, robot {hello['robot']['name']}")
    print("ops:", ", ".join(hello["ops"]))

    print("map:", c.call("map.update", scene="pallet_10"))
    for r in c.call("map.query", points=[[0.0, 0.0], [0.56, 0.0], [1.0, 0.0]])["results"]:
        print(f"  ({r['x']:.2f}, {r['y']:.2f}) h={r['height']:.3f} safe={r['safe']} "
              f"margin={r['margin']:.3f}")

    # A scan goes as a float32 attachment, not as JSON text.
    scan = Attachment.points("points", [(0.02 * i, 0.02 * j - 0.5, 0.0)
                                        for i in range(50) for j in range(50)])
    try:
        print("scan:", c.call("map.update", [scan], origin=[0.0, 0.0, 0.8], mode="add"))
    except ServiceError as e:
        print("scan:", e)

    try:
        plan = c.call("plan", terrain="current", gait="crawl", goal=[1.0, 0.0, 0.0],
                      deadline_ms=120000)
        print("plan:", plan["solver"])
    except ServiceError as e:
        print("plan:", e)
    print("status:", c.call("status")["requests"])
