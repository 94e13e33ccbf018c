"""FlightCore.run steps per second on one core (N steps of a turn, tracker at 4 Hz)."""
import math, sys, time
import numpy as np
import ssis

n = int(sys.argv[1]) if len(sys.argv) > 1 else 1_000_000
dt = 0.005
w = math.radians(0.1)
axes = np.array(ssis.Table.default().axes())
rng = np.random.default_rng(1)
dtheta = (axes @ np.array([0, 0, w * dt]))[None, :] + rng.normal(0, 2e-8, size=(n, 4))
t = np.arange(1, n + 1) * dt
st = np.full(n, math.nan); sq = np.zeros((n, 4)); sq[:, 0] = 1
k = np.arange(49, n, 50); st[k] = t[k]; h = w * t[k] / 2
sq[k] = np.stack([np.cos(h), 0 * h, 0 * h, np.sin(h)], axis=1)
core = ssis.FlightCore()
t0 = time.perf_counter(); c0 = time.process_time(); r = core.run(dtheta, st, sq); el = time.perf_counter() - t0; cpu = time.process_time() - c0
print(f"FlightCore.run: {n} steps in {el:.3f} s wall, {cpu:.3f} s CPU = {n / cpu / 1e6:.2f} M steps per CPU second; aligned at end {bool(r.aligned[-1])}, events {len(r.events)}")
c2 = ssis.FlightCore(); m = 20000
t0 = time.perf_counter()
for i in range(m):
    s = None if math.isnan(st[i]) else (st[i], sq[i])
    c2.step(dtheta[i], s)
el2 = time.perf_counter() - t0
print(f"FlightCore.step loop: {m} steps in {el2:.3f} s = {m / el2:.0f} steps/s")
