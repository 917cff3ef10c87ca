#!/usr/bin/env python3
"""Starts `terrastride serve` on a loopback port, makes one attack on it, and prints the server's
resident memory over time (docs/protocol.md, "Limits"). Standard library only; Linux (/proc).

  python3 probe_server_memory.py BINARY stalled [--count 24] [--bytes 62914560] [-- SERVE_OPTIONS]
      COUNT connections each send BYTES of a frame announcing one byte more, then stall.
  python3 probe_server_memory.py BINARY nonreaders [--count 6] [--bytes 234000000] [-- ...]
      COUNT connections each ask for a reply of BYTES (debug.sleep's reply_bytes; the server runs
      with --debug-ops) and never read.

Prints the peak and the memory at 10, 15 and 40 s, then the server's "dropped" lines.
"""
import argparse
import json
import re
import socket
import struct
import subprocess
import time


def frame(header):
    text = json.dumps(header).encode()
    body = struct.pack(">I", len(text)) + text
    return struct.pack(">I", len(body)) + body


def stalled(port, count, nbytes):
    chunk = b" " * (1 << 20)
    socks = []
    for _ in range(count):
        s = socket.create_connection(("127.0.0.1", port))
        s.settimeout(30)
        try:
            s.sendall(struct.pack(">I", nbytes + 1))
            left = nbytes
            while left > 0:
                s.sendall(chunk[:min(left, len(chunk))])
                left -= min(left, len(chunk))
        except OSError:
            pass  # refused for the budget: the server closed it
        socks.append(s)
    return socks


def nonreaders(port, count, nbytes):
    socks = []
    for i in range(count):
        s = socket.create_connection(("127.0.0.1", port))
        s.sendall(frame({"v": 1, "id": i, "op": "debug.sleep", "ms": 0, "reply_bytes": nbytes}))
        socks.append(s)
    return socks


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("binary")
    parser.add_argument("attack", choices=["stalled", "nonreaders"])
    parser.add_argument("--count", type=int)
    parser.add_argument("--bytes", type=int)
    parser.add_argument("--seconds", type=float, default=40.0)
    parser.add_argument("serve_options", nargs="*")
    a = parser.parse_args()
    count = a.count or (24 if a.attack == "stalled" else 6)
    nbytes = a.bytes or (60 << 20 if a.attack == "stalled" else 234000000)
    options = ["--debug-ops"] if a.attack == "nonreaders" else []
    server = subprocess.Popen([a.binary, "serve", "--listen", "tcp://127.0.0.1:0"] + options +
                              a.serve_options, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True)
    port = int(re.search(r":(\d+)$", server.stdout.readline().strip()).group(1))

    def rss_mib():
        with open("/proc/%d/status" % server.pid) as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
        return -1.0

    start = time.time()
    socks = (stalled if a.attack == "stalled" else nonreaders)(port, count, nbytes)
    sent = time.time() - start
    samples = []
    while time.time() - start < a.seconds:
        samples.append((time.time() - start, rss_mib()))
        time.sleep(0.5)

    def at(t):
        later = [r for tt, r in samples if tt >= t]
        return later[0] if later else samples[-1][1]

    print("%s: %d x %d bytes, sent in %.1f s; peak RSS %.0f MiB; at 10 s %.0f, 15 s %.0f, "
          "%.0f s %.0f MiB" % (a.attack, count, nbytes, sent, max(r for _, r in samples), at(10),
                               at(15), a.seconds, samples[-1][1]))
    for s in socks:
        s.close()
    server.terminate()
    out = server.communicate(timeout=30)[0]
    for line in out.splitlines():
        if "dropped" in line:
            print(line)


if __name__ == "__main__":
    main()
