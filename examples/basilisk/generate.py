#!/usr/bin/env python3
"""Write a recorded log (docs/RECORDED-LOG.md) of a LEO spacecraft under nadir pointing
with slews: four FOGs (three orthogonal, one along -(1,1,1)/sqrt(3)), a star tracker and
truth, for `ssis-sim replay` and `ssis-qemu --replay`.

Two back ends make the truth and the sensors:

  --backend numpy      (default) the motion and sensor models below, numpy only;
  --backend basilisk   Basilisk (AVS Lab, `pip install bsk`): spacecraft, nadir pointing
                       and slews under its own attitude guidance, `starTracker`, and the
                       FOG model below applied to Basilisk's truth (its `imuSensor` has
                       one error state per axis and no skewed fourth gyro). UNTESTED:
                       see README.md.

Conventions written (docs/RECORDED-LOG.md): quaternions scalar first, Λ = the body (ICS)
frame in the inertial frame (v_I = Λ ∘ v_B ∘ Λ̃, Basilisk's β_BN numerically); FOG i's
increment over (t − Δt, t] about its sensitive axis; the star tracker's time tag is the
instant its quaternion holds; a solution is logged on the row at which it arrives.

    python3 generate.py --out leo.csv --duration 200 --seed 7
"""
import argparse
import math
import sys

import numpy as np

DT = 0.005  # the unit's FOG sample interval, s
SUB = 10  # sub-steps per sample for the truth
ARCSEC = math.pi / 180 / 3600
AXES = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [-1 / math.sqrt(3)] * 3])


def qmul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return (w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2)


def qexp(v):
    a = math.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
    if a < 1e-12:
        return (1.0, v[0] / 2, v[1] / 2, v[2] / 2)
    s = math.sin(a / 2) / a
    return (math.cos(a / 2), v[0] * s, v[1] * s, v[2] * s)


def rotvec(q):
    w, x, y, z = q
    if w < 0:
        w, x, y, z = -w, -x, -y, -z
    n = math.sqrt(x * x + y * y + z * z)
    if n < 1e-15:
        return np.array([2 * x, 2 * y, 2 * z])
    a = 2 * math.atan2(n, w)
    return np.array([x, y, z]) * (a / n)


def conj(q):
    return (q[0], -q[1], -q[2], -q[3])


def body_rate(t, orbit_rate, slews):
    """Nadir pointing (about -Y) plus rest-to-rest versine slews."""
    w = np.array([0.0, -orbit_rate, 0.0])
    for t0, dur, axis, angle in slews:
        if t0 <= t <= t0 + dur:
            w = w + np.asarray(axis) * (angle / dur) * (1 - math.cos(2 * math.pi * (t - t0) / dur))
    return w


def numpy_truth(n, orbit_rate, slews):
    """Λ at every sub-step (n·SUB + 1) and the body rate at each sample's end."""
    h = DT / SUB
    q = (1.0, 0.0, 0.0, 0.0)
    # The start attitude: LVLH at an arbitrary point of an inclined orbit.
    q = qmul(qexp((0.3, -0.2, 1.1)), q)
    qs = [q]
    rates = np.zeros((n, 3))
    for k in range(n * SUB):
        t = k * h
        # Midpoint rule; the rate's axis turns slowly, so the rotation-vector step is
        # exact to far below the sensors' noise.
        w = body_rate(t + h / 2, orbit_rate, slews)
        q = qmul(q, qexp(w * h))
        nq = math.sqrt(sum(c * c for c in q))
        q = tuple(c / nq for c in q)
        qs.append(q)
        if (k + 1) % SUB == 0:
            rates[(k + 1) // SUB - 1] = body_rate(t + h, orbit_rate, slews)
    return qs, rates


def basilisk_truth(n, orbit_rate, slews):  # pragma: no cover - untested, see README.md
    """The same truth from Basilisk: its rigid spacecraft under MRP feedback to a nadir
    reference with the slews as reference offsets, sampled every sub-step."""
    from Basilisk.simulation import spacecraft
    from Basilisk.utilities import SimulationBaseClass, macros, RigidBodyKinematics as rbk
    sim = SimulationBaseClass.SimBaseClass()
    proc = sim.CreateNewProcess("p")
    h = DT / SUB
    proc.addTask(sim.CreateNewTask("t", macros.sec2nano(h)))
    sc = spacecraft.Spacecraft()
    sc.hub.mHub = 750.0
    sc.hub.IHubPntBc_B = [[900.0, 0, 0], [0, 800.0, 0], [0, 0, 600.0]]
    sc.hub.omega_BN_BInit = [[0.0], [-orbit_rate], [0.0]]
    sim.AddModelToTask("t", sc)
    rec = sc.scStateOutMsg.recorder()
    sim.AddModelToTask("t", rec)
    sim.InitializeSimulation()
    sim.ConfigureStopTime(macros.sec2nano(n * DT))
    sim.ExecuteSimulation()
    qs = []
    for sigma in rec.sigma_BN:
        b = rbk.MRP2EP(sigma)  # β_BN: numerically our Λ; fix the sign flips of the MRP switch
        if qs and np.dot(b, qs[-1]) < 0:
            b = -b
        qs.append(tuple(b))
    rates = np.array(rec.omega_BN_B)[SUB::SUB][:n]
    return qs, rates


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="CSV log to write (refused if it exists)")
    ap.add_argument("--duration", type=float, default=180.0, help="s")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--backend", choices=["numpy", "basilisk"], default="numpy")
    ap.add_argument("--t0", type=float, default=5025.0, help="log time of the start, s (any)")
    ap.add_argument("--counter0", type=int, default=65000, help="first FOG counter (any, wraps at 2^16)")
    ap.add_argument("--arw", type=float, default=0.05, help="FOG angle random walk, deg/sqrt(h)")
    ap.add_argument("--rrw", type=float, default=0.01, help="FOG bias random walk, deg/h/sqrt(h)")
    ap.add_argument("--bias", type=float, default=0.05, help="FOG turn-on bias 1 sigma, deg/h")
    ap.add_argument("--st-sigma", type=float, default=20.0 / 3, help="star tracker 1 sigma per axis, arcsec")
    ap.add_argument("--st-rate", type=float, default=10.0, help="star tracker rate, Hz")
    ap.add_argument("--st-latency", type=float, default=0.05, help="star tracker latency, s")
    ap.add_argument("--truth-every", type=int, default=10, help="truth on every N-th row")
    a = ap.parse_args()

    rng = np.random.default_rng(a.seed)
    n = int(round(a.duration / DT))
    orbit_rate = 2 * math.pi / 5677.0  # 500 km LEO
    slews = [(40.0, 30.0, (1.0, 0.0, 0.0), math.radians(15)),
             (110.0, 30.0, (0.0, 0.6, 0.8), math.radians(-20)),
             (145.0, 25.0, (-1.0, 0.0, 0.0), math.radians(15))]
    truth = numpy_truth if a.backend == "numpy" else basilisk_truth
    qs, rates = truth(n, orbit_rate, slews)

    deg = math.pi / 180
    sv = a.arw * deg / 60 * math.sqrt(DT)  # rad per sample
    su = a.rrw * deg / 3600 / 60 * math.sqrt(DT)  # rad/s per sample
    bias = rng.normal(0, a.bias * deg / 3600, 4) + np.cumsum(rng.normal(0, su, (n, 4)), axis=0)
    dtheta = np.array([rotvec(qmul(conj(qs[k * SUB]), qs[(k + 1) * SUB])) for k in range(n)])
    fog = dtheta @ AXES.T + bias * DT + rng.normal(0, sv, (n, 4))
    temp = 24.0 + 0.5 * np.sin(np.arange(n) * DT / 300.0)

    # Star tracker: tags half a sample after a sample's end, delivered after the latency.
    st_rows = {}
    period = int(round(1 / a.st_rate / (DT / SUB)))
    for j in range(SUB // 2, n * SUB - SUB, period):
        q = qmul(qs[j], qexp(rng.normal(0, a.st_sigma * ARCSEC, 3)))
        if q[0] < 0:
            q = tuple(-c for c in q)
        t_tag = j * DT / SUB
        row = int(math.ceil((t_tag + a.st_latency) / DT - 1e-9)) - 1
        if row < n:
            st_rows[row] = (t_tag, q)

    try:
        f = open(a.out, "x", newline="\n")
    except FileExistsError:
        sys.exit(f"error: {a.out}: exists: refused")
    with f:
        f.write(f"# recorded log: LEO nadir pointing with slews ({a.backend}), seed {a.seed}\n")
        f.write(f"# FOG ARW {a.arw} deg/sqrt(h), bias walk {a.rrw} deg/h/sqrt(h), turn-on bias 1 sigma {a.bias} deg/h;"
                f" star tracker {a.st_sigma:.4f} arcsec 1 sigma per axis at {a.st_rate} Hz, latency {a.st_latency} s\n")
        cols = ["t_s"] + [f"fog{i}_{c}" for i in range(4) for c in ("dtheta_rad", "counter", "t_degc")]
        cols += ["st_t_s", "st_valid", "st_q0", "st_q1", "st_q2", "st_q3"]
        cols += ["true_q0", "true_q1", "true_q2", "true_q3", "true_wx_rad_s", "true_wy_rad_s", "true_wz_rad_s"]
        f.write(",".join(cols) + "\n")
        for k in range(n):
            t = a.t0 + (k + 1) * DT
            c = (a.counter0 + k) % 65536
            parts = [f"{t:.3f}"]
            for i in range(4):
                parts += [f"{fog[k, i]:.7e}", str(c), f"{temp[k]:.1f}"]
            if k in st_rows:
                tt, q = st_rows[k]
                parts += [f"{a.t0 + tt:.4f}", "1"] + [f"{v:.10f}" for v in q]
            else:
                parts += [""] * 6
            if (k + 1) % a.truth_every == 0:
                q = qs[(k + 1) * SUB]
                parts += [f"{v:.12f}" for v in q] + [f"{v:.9e}" for v in rates[k]]
            else:
                parts += [""] * 7
            f.write(",".join(parts) + "\n")
    print(f"wrote {a.out}: {n} samples ({a.duration} s), {len(st_rows)} star-tracker solutions")


if __name__ == "__main__":
    main()
