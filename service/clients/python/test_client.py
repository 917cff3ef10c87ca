#!/usr/bin/env python3
"""Drives a running `terrastride serve --debug-ops --workers 1 --queue 1` through the Python client:
every operation, pipelining, cancel, deadline, busy, hostile input. Prints OK on success.

    python3 test_client.py tcp://127.0.0.1:PORT
"""
import os
import math
import time
import struct
import sys

from terrastride_client import Attachment, Client, PlanningSession, ServiceError


def expect_error(code, fn):
    try:
        fn()
    except ServiceError as e:
        assert e.code == code, f"expected {code}, got {e.code}: {e.message}"
        return e
    raise AssertionError(f"expected error {code}, got success")


def wait_idle(c):
    """Cancelled jobs hold their worker until they notice; wait until none runs."""
    for _ in range(2000):
        q = c.call("status")["queue"]
        if q["running"] == 0 and q["length"] == 0:
            return
        time.sleep(0.005)
    raise AssertionError("workers never became idle")


def cdr_pointcloud2(points, frame, stamp=(1700000000, 5)):
    """A sensor_msgs/PointCloud2 in CDR little endian (what rclpy's serialize_message gives):
    one row, fields x y z float32, 12-byte points."""
    out = bytearray(b"\x00\x01\x00\x00")

    def align(n):
        while (len(out) - 4) % n:
            out.append(0)

    def u32(v):
        align(4)
        out.extend(struct.pack("<I", v))

    def string(s):
        u32(len(s) + 1)
        out.extend(s.encode() + b"\x00")

    u32(stamp[0])
    u32(stamp[1])
    string(frame)
    u32(1)
    u32(len(points))
    u32(3)
    for k, name in enumerate("xyz"):
        string(name)
        u32(4 * k)
        out.append(7)  # FLOAT32
        u32(1)
    out.append(0)  # is_bigendian
    u32(12)
    u32(12 * len(points))
    u32(12 * len(points))
    for p in points:
        out.extend(struct.pack("<3f", *p))
    out.append(1)  # is_dense
    return bytes(out)


def pointcloud2_updates(c):
    """map.update with a serialised PointCloud2 and the sensor's pose (docs/protocol.md)."""
    floor = [(0.01 * i - 0.5, 0.01 * j - 0.5, -0.5) for i in range(100) for j in range(100)]
    floor[7] = (math.nan, math.nan, math.nan)  # an organised cloud's miss: dropped and counted
    msg = cdr_pointcloud2(floor, "lidar")
    up = c.call("map.update", [Attachment.raw("pointcloud2", msg)], mode="replace",
                pose=[2.0, 1.0, 0.6, 0.0, 0.0, 0.0, 1.0], frame="lidar")
    assert up["source"] == "pointcloud2", up
    info = up["stats"]["pointcloud2"]
    assert info["points"] == 9999 and info["non_finite"] == 1 and info["frame"] == "lidar", info
    res = c.call("map.query", points=[[2.0, 1.0]])["results"][0]
    assert abs(res["height"] - 0.1) < 1e-3 and res["observed"], res
    # A message as a ROS 2 recorder stored it (the db3 fixture, written with
    # @foxglove/rosmsg2-serialization's bytes): the same payload a driver publishes.
    import os
    import sqlite3
    db3 = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "..", "tests",
                       "fixtures", "bags", "scan.db3")
    if os.path.exists(db3):
        con = sqlite3.connect(f"file:{db3}?mode=ro", uri=True)
        (data,) = con.execute("SELECT m.data FROM messages m JOIN topics t ON m.topic_id = t.id "
                              "WHERE t.name = '/points' ORDER BY m.timestamp LIMIT 1").fetchone()
        con.close()
        up = c.call("map.update", [Attachment.raw("pointcloud2", data)], mode="replace",
                    pose=[0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 1.0], frame="lidar")
        info = up["stats"]["pointcloud2"]
        assert info["width"] * info["height"] == info["points"] + info["non_finite"], info
        assert info["points"] > 100, info
    # Bad payloads: bad_request naming the problem; the connection stays usable.
    for att, fields, part in (
            (Attachment.raw("pointcloud2", msg[:len(msg) // 2]), {}, "cut short"),
            (Attachment.raw("pointcloud2", msg), {"pose": [0, 0, 0, 0, 0, 0, 3]}, "has norm 3, not 1"),
            (Attachment.raw("pointcloud2", msg), {"frame": "camera"}, "'lidar'"),
            (Attachment("pointcloud2", (3,), [1, 2, 3]), {}, "uint8")):
        f = {"pose": [2.0, 1.0, 0.6, 0.0, 0.0, 0.0, 1.0]}
        f.update(fields)
        e = expect_error("bad_request", lambda: c.call("map.update", [att], **f))
        assert part in e.message, (part, e.message)
    e = expect_error("bad_request", lambda: c.call(
        "map.update", [Attachment.raw("pointcloud2", msg)], pose=[0, 0, 1]))
    assert "pose" in e.message, e.message
    assert "uint8" in c.call("hello")["capabilities"]["attachment_dtypes"]
    c.call("map.update", scene="pallet_10")


def main(address):
    # TERRASTRIDE_CLIENT_TIMEOUT: the reply timeout (s), longer for a server under a sanitizer.
    timeout = float(os.environ.get("TERRASTRIDE_CLIENT_TIMEOUT", "30"))
    with Client.connect(address, timeout=timeout) as c:
        hello = c.call("hello")
        assert hello["protocol"] == 1 and hello["robot"]["name"] == "hyq", hello
        for op in ("map.update", "map.query", "map.clear", "plan", "check", "simulate", "cancel",
                   "status"):
            assert op in hello["ops"], op

        up = c.call("map.update", scene="pallet_10")
        res = c.call("map.query", points=[[1.0, 0.0], [0.56, 0.0]])
        assert res["generation"] == up["generation"]
        top, edge = res["results"]
        assert abs(top["height"] - 0.10) < 1e-12 and top["safe"] is True, top
        assert edge["safe"] is False and edge["margin"] < 0, edge
        res = c.call("map.query", [Attachment("points", (1, 2), [1.0, 0.0])])
        assert abs(res["results"][0]["height"] - 0.10) < 1e-6

        # Pipelining: 100 requests out, 100 replies back, matched by id.
        ids = [c.send("map.query", points=[[0.01 * i, 0.0]]) for i in range(100)]
        seen = {}
        for _ in ids:
            header, _ = c.receive()
            seen[header["id"]] = header["result"]["results"][0]["x"]
        assert sorted(seen) == sorted(ids)
        assert all(abs(seen[i] - 0.01 * (i - ids[0])) < 1e-12 for i in ids)

        # Cancel a running job, then a deadline, then busy (1 worker, queue 1).
        long_id = c.send("debug.sleep", ms=20000)
        c.call("status")
        r = c.call("cancel", target=long_id)
        assert r["cancelled"] is True, r
        header, _ = c.wait_for(long_id)
        assert header["error"]["code"] == "cancelled", header
        expect_error("deadline_exceeded", lambda: c.call("debug.sleep", ms=20000, deadline_ms=50))
        wait_idle(c)
        a = c.send("debug.sleep", ms=20000)
        b = c.send("debug.sleep", ms=20000)
        c.call("status")
        expect_error("busy", lambda: c.call("debug.sleep", ms=1))
        for t in (a, b):
            c.call("cancel", target=t)
            assert c.wait_for(t)[0]["error"]["code"] == "cancelled"

        # Hostile input: errors name the problem; the connection stays usable.
        expect_error("unknown_op", lambda: c.call("self.destruct"))
        e = expect_error("bad_request", lambda: c.call(
            "map.update", [Attachment("points", (1, 3), [0.0, math.nan, 0.0])], origin=[0, 0, 1]))
        assert "non-finite" in e.message, e.message
        e = expect_error("bad_request", lambda: c.call("map.query", points="all"))
        assert "points" in e.message
        body = struct.pack(">I", 5) + b"{oops"
        c.send_raw(struct.pack(">I", len(body)) + body)
        header, _ = c.receive()
        assert header["error"]["code"] == "bad_json" and header["id"] is None, header

        pointcloud2_updates(c)

        # Plan and check: a real result or an honest "unavailable".
        for op, fields in (("plan", {"terrain": "flat", "goal": [0.3, 0.0, 0.0]}),
                           ("check", {"plan": {}})):
            header, _ = c.request(op, **fields)
            if not header["ok"]:
                assert header["error"]["code"] in ("unavailable", "bad_request"), header

        # A plan with its samples as a float32 table: one value per sample in every column,
        # times increasing, every foot's contact flag 0 or 1.
        result, cols = c.plan_table(terrain="flat", duration=2.4, goal=[0.3, 0.0, 0.0])
        n = result["samples"]["rows"]
        assert n > 100 and all(len(v) == n for v in cols.values()), (n, len(cols))
        assert all(a < b for a, b in zip(cols["t"], cols["t"][1:]))
        for foot in result["feet"]:
            assert set(cols[foot + ".contact"]) <= {0.0, 1.0}
        assert abs(cols["base.position.x"][-1] - 0.3) < 1e-3, cols["base.position.x"][-1]

        # The plan executed in MuJoCo on the exact flat scene: a verdict with its figures.
        planned = c.call("plan", terrain="flat", duration=2.4, goal=[0.3, 0.0, 0.0])
        sim = c.call("simulate", plan=planned, terrain="flat")
        assert sim["verdict"] in ("pass", "warn", "fail") and not sim["fell"], sim
        assert sim["position_error_rms_m"] < 0.02, sim["position_error_rms_m"]
        e = expect_error("bad_request", lambda: c.call("simulate", plan=planned, dt=1.0))
        assert "dt" in e.message, e.message

        # A planning session: re-plans from measured states, a failed step, close.
        with PlanningSession(c, terrain="flat", duration=2.4, goal=[0.3, 0.0, 0.0],
                             horizon=1.0, sample_dt=0.02) as s:
            ref = s.reference["samples"]
            at = next(x for x in ref if abs(x["t"] - 0.2) < 1e-9)["base"]
            pos = list(at["position"])
            pos[1] += 0.01
            step = s.step(0.2, {"base": {"position": pos}}, budget_ms=0)
            assert step["start_time"] == 0.2 and step["solver"]["status"] == "optimal", step
            assert abs(step["samples"][0]["base"]["position"][1] - pos[1]) < 1e-9
            e = expect_error("failed", lambda: s.step(0.3, {"base": {"position": [0.3, 0.4, 0.9]}},
                                                      budget_ms=0))
            assert "still violated" in e.message, e.message
            # With a budget (50 ms by default) the step answers with the current plan instead.
            fb = s.step(0.3, {"base": {"position": [0.3, 0.4, 0.9]}})
            assert fb["fallback"] and fb["fallback_reason"] in ("solve_failed", "deadline"), fb
            assert s.step(0.3, budget_ms=0)["solver"]["status"] == "optimal"
            result, columns = s.step_table(0.4, {"base": {"position": pos}}, budget_ms=0)
            assert result["start_time"] == 0.4 and result["samples"]["rows"] == len(columns["t"])
            assert abs(columns["base.position.y"][0] - pos[1]) < 1e-6, columns["base.position.y"][0]
        assert c.call("plan.session.status")["open"] == 0

        c.call("map.clear")
        expect_error("no_map", lambda: c.call("map.query", points=[[0, 0]]))
        st = c.call("status")
        assert st["requests"]["cancelled"] >= 3 and st["requests"]["busy"] >= 1, st
    print("OK")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "tcp://127.0.0.1:7700")
