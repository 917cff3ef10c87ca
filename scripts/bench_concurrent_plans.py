#!/usr/bin/env python3
"""Throughput of N plans at once on one `terrastride serve` (plans run in child processes).

    python3 scripts/bench_concurrent_plans.py build/terrastride WORKERS N SCENE [serve flags...]
    e.g. ... build/terrastride 2 2 pallet_15                      (each plan in its own process)
         ... build/terrastride 2 2 pallet_15 --plans-in-process   (one solve at a time)
Prints wall time, plans per second, each plan's latency and the server's plan-process counters.
"""
import os, sys, time, threading, subprocess, json
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'service', 'clients', 'python'))
from terrastride_client import Client, ServiceError
binary, workers, n, scene, extra = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4], sys.argv[5:]
srv = subprocess.Popen([binary, 'serve', '--listen', 'tcp://127.0.0.1:0', '--workers', str(workers), '--queue', '64'] + extra,
                       stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
addr = srv.stdout.readline().split()[1]
res = []
def one(i):
    with Client.connect(addr, timeout=120) as c:
        t = time.time()
        try:
            r = c.call('plan', terrain=scene, duration=2.4 if scene == 'flat' else 11.0, samples='attachment')
            res.append(('ok', r['solver']['status'] if 'solver' in r else r.get('success'), time.time() - t))
        except ServiceError as e:
            res.append(('err', e.code, str(e)[:200]))
        except Exception as e:
            res.append(('exc', repr(e)[:200], 0))
t0 = time.time()
th = [threading.Thread(target=one, args=(i,)) for i in range(n)]
[x.start() for x in th]; [x.join() for x in th]
wall = time.time() - t0
alive = srv.poll() is None
with Client.connect(addr) as c:
    st = c.call('status')
print(json.dumps({'workers': workers, 'n': n, 'wall_s': round(wall, 3), 'plans_per_s': round(n / wall, 2), 'server_alive': alive,
                  'results': res, 'plan_processes': st.get('plan_processes')}))
srv.terminate(); srv.wait()
