#!/usr/bin/env python3
"""Write a recorded log (docs/RECORDED-LOG.md) of a LEO spacecraft under nadir pointing
with slews: four FOGs (three orthogonal, one along -(1,1,1)/sqrt(3)), a star tracker and
truth, for `ssis-sim replay` and `ssis-qemu --replay`.

Two back ends make the truth and the sensors:

  --backend numpy      (default) the motion and sensor models below, numpy only;
  --backend basilisk   Basilisk (AVS Lab, `pip install bsk ./python`): the package's LEO
                       spacecraft (`ssis.basilisk.Leo`), nadir pointing and slews under
                       its own attitude guidance, `starTracker`, and the
                       FOG model below applied to Basilisk's truth (its `imuSensor` has
                       one error state per axis and no skewed fourth gyro).

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


def numpy_truth(n, args, rng):
    """The numpy back end: Λ at each sample end (n + 1), the body rate at each sample's
    end, and the tracker's solutions (time tag, Λ* with q0 >= 0), from rotation-vector
    steps of DT/SUB and the tracker's noise as a rotation vector of args.st_sigma per axis."""
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
        w = body_rate(t + h / 2, args.orbit_rate, args.slews)
        q = qmul(q, qexp(w * h))
        nq = math.sqrt(sum(c * c for c in q))
        q = tuple(c / nq for c in q)
        qs.append(q)
        if (k + 1) % SUB == 0:
            rates[(k + 1) // SUB - 1] = body_rate(t + h, args.orbit_rate, args.slews)
    # Star tracker: tags half a sample after a sample's end.
    sols = []
    period = int(round(1 / args.st_rate / h))
    for j in range(SUB // 2, n * SUB - SUB, period):
        s = qmul(qs[j], qexp(rng.normal(0, args.st_sigma * ARCSEC, 3)))
        if s[0] < 0:
            s = tuple(-c for c in s)
        sols.append((j * h, s))
    return qs[::SUB], rates, sols


def basilisk_truth(n, args, rng):
    """Truth and star-tracker solutions from Basilisk 2.12.1 (`pip install bsk`) on the
    package's LEO spacecraft (`ssis.basilisk.Leo`, `pip install ./python`).

    A rigid spacecraft (`spacecraft`, 750 kg, inertia diag(900, 800, 600) kg m^2) in a
    500-km circular orbit (inclination 51.6 deg) about a point-mass Earth; nadir pointing
    from `hillPoint` (Hill frame: x radial, y along track, z orbit normal), the slews
    (`ssis.basilisk.slew_events`, the ones `--backend numpy` turns) as steps of
    `attTrackingError`'s reference offset sigma_R0R (MRP-step guidance), and
    `mrpFeedback` commanding `extForceTorque`; `simpleNav` (no noise) closes the loop.
    `starTracker` (noise matrix set explicitly: its default is zero; white noise, A = 0)
    at the tracker's rate on its own task (after the dynamics at the same instant).

    Returns Λ at each sample end (n + 1, β_BN from sigma_BN: numerically our Λ, signs made
    continuous across the MRP switch), the body rate at each sample's end, and the
    tracker's solutions (time tag, β_CN with q0 >= 0)."""
    from Basilisk.simulation import starTracker
    from Basilisk.utilities import RigidBodyKinematics as rbk
    from Basilisk.utilities import SimulationBaseClass, macros

    from ssis.basilisk import Leo

    h = DT / SUB
    sim = SimulationBaseClass.SimBaseClass()
    proc = sim.CreateNewProcess("p")
    proc.addTask(sim.CreateNewTask("dyn", macros.sec2nano(h)), 100)
    proc.addTask(sim.CreateNewTask("st", macros.sec2nano(1.0 / args.st_rate)), 50)
    leo = Leo(sim, "dyn")

    st = starTracker.StarTracker()
    st.scStateInMsg.subscribeTo(leo.sc.scStateOutMsg)
    st.dcm_CB = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    # Measured on 2.12.1 (2,000 solutions): the error per axis has the standard deviation
    # of the PMatrix diagonal in radians (not 4x it, as an MRP error set would).
    p = args.st_sigma * ARCSEC
    st.PMatrix = [[p, 0.0, 0.0], [0.0, p, 0.0], [0.0, 0.0, p]]
    st.setAMatrix([[0.0] * 3] * 3)
    st.setWalkBounds([1.0e3] * 3)
    st.RNGSeed = int(rng.integers(1, 2**31 - 1))
    sim.AddModelToTask("st", st)

    rec = leo.sc.scStateOutMsg.recorder(macros.sec2nano(DT))
    sim.AddModelToTask("dyn", rec)
    st_rec = st.sensorOutMsg.recorder()
    sim.AddModelToTask("st", st_rec)

    sim.InitializeSimulation()
    leo.fly(n * DT)

    qs = []
    for sigma in rec.sigma_BN[: n + 1]:
        b = rbk.MRP2EP(sigma)  # β_BN: numerically our Λ; fix the sign flips of the MRP switch
        if qs and np.dot(b, qs[-1]) < 0:
            b = -b
        qs.append(tuple(b))
    if len(qs) != n + 1:
        sys.exit(f"error: Basilisk recorded {len(qs)} states, expected {n + 1}")
    rates = np.array(rec.omega_BN_B)[1 : n + 1]
    sols = []
    for t_ns, q in zip(st_rec.timeTag, st_rec.qInrtl2Case):
        q = np.asarray(q, dtype=float)
        if q[0] < 0:
            q = -q
        t_tag = t_ns * 1e-9
        if 0 < t_tag < n * DT:
            sols.append((t_tag, tuple(q)))
    return qs, rates, sols


def with_lfe(sols, sigma, tau, rng):
    """The tracker's low-frequency error: a first-order Gauss-Markov rotation per tracker
    axis (the tracker frame is the body's), c_k = phi c_(k-1) + sigma sqrt(1 - phi^2) w,
    phi = exp(-dt/tau), c_0 from its stationary distribution, on each solution after the
    tracker's own white noise."""
    out, c, t_last = [], rng.normal(0, sigma, 3), None
    for t_tag, q in sols:
        if t_last is not None:
            phi = math.exp(-(t_tag - t_last) / tau)
            c = phi * c + sigma * math.sqrt(1 - phi * phi) * rng.normal(0, 1, 3)
        t_last = t_tag
        s = qmul(q, qexp(c))
        out.append((t_tag, s if s[0] >= 0 else tuple(-x for x in s)))
    return out


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
    ap.add_argument("--st-lfe-sigma", type=float, default=0.0,
                    help="star tracker low-frequency error, 1 sigma per tracker axis, arcsec (0: none)")
    ap.add_argument("--st-lfe-tau", type=float, default=300.0, help="its correlation time, s")
    ap.add_argument("--truth-every", type=int, default=10, help="truth on every N-th row")
    ap.add_argument("--compact", action="store_true", help="6 digits, FOG1's counter alone, no temperatures")
    a = ap.parse_args()

    rng = np.random.default_rng(a.seed)
    n = int(round(a.duration / DT))
    a.orbit_rate = 2 * math.pi / 5677.0  # 500 km LEO
    # Three rest-to-rest slews in every 180 s (Basilisk: back to nadir at each 180 s).
    a.slews = []
    for p in range(int(math.ceil(a.duration / 180.0))):
        b0 = 180.0 * p
        a.slews += [(b0 + 40.0, 30.0, (1.0, 0.0, 0.0), math.radians(15)),
                    (b0 + 110.0, 30.0, (0.0, 0.6, 0.8), math.radians(-20)),
                    (b0 + 145.0, 25.0, (-1.0, 0.0, 0.0), math.radians(15))]
    truth = numpy_truth if a.backend == "numpy" else basilisk_truth
    qs, rates, sols = truth(n, a, rng)
    if a.st_lfe_sigma > 0:
        sols = with_lfe(sols, a.st_lfe_sigma * ARCSEC, a.st_lfe_tau, rng)

    deg = math.pi / 180
    sv = a.arw * deg / 60 * math.sqrt(DT)  # rad per sample
    su = a.rrw * deg / 3600 / 60 * math.sqrt(DT)  # rad/s per sample
    bias = rng.normal(0, a.bias * deg / 3600, 4) + np.cumsum(rng.normal(0, su, (n, 4)), axis=0)
    # Each FOG's increment: the rotation between the truth's attitudes at the sample's
    # ends, about its sensitive axis, plus its bias and angle random walk.
    dtheta = np.array([rotvec(qmul(conj(qs[k]), qs[k + 1])) for k in range(n)])
    fog = dtheta @ AXES.T + bias * DT + rng.normal(0, sv, (n, 4))
    temp = 24.0 + 0.5 * np.sin(np.arange(n) * DT / 300.0)

    # A solution is logged on the row at which it arrives, the latency after its tag.
    st_rows = {}
    for t_tag, q in sols:
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
                f" star tracker {a.st_sigma:.4f} arcsec 1 sigma per axis at {a.st_rate} Hz, latency {a.st_latency} s"
                + (f", low-frequency error {a.st_lfe_sigma} arcsec 1 sigma over {a.st_lfe_tau} s" if a.st_lfe_sigma > 0 else "")
                + "\n")
        # Compact: 6 significant digits (the noise per sample is 1e-6 rad), FOG1's counter
        # alone, no temperatures (the reader takes 25 degC).
        per_fog = [("dtheta_rad", "counter", "t_degc")] * 4 if not a.compact else [("dtheta_rad", "counter")] + [("dtheta_rad",)] * 3
        cols = ["t_s"] + [f"fog{i}_{c}" for i in range(4) for c in per_fog[i]]
        cols += ["st_t_s", "st_valid", "st_q0", "st_q1", "st_q2", "st_q3"]
        cols += ["true_q0", "true_q1", "true_q2", "true_q3", "true_wx_rad_s", "true_wy_rad_s", "true_wz_rad_s"]
        f.write(",".join(cols) + "\n")
        for k in range(n):
            t = a.t0 + (k + 1) * DT
            c = (a.counter0 + k) % 65536
            parts = [f"{t:.3f}"]
            for i in range(4):
                fields = {"dtheta_rad": f"{fog[k, i]:.{5 if a.compact else 7}e}", "counter": str(c), "t_degc": f"{temp[k]:.1f}"}
                parts += [fields[name] for name in per_fog[i]]
            if k in st_rows:
                tt, q = st_rows[k]
                parts += [f"{a.t0 + tt:.4f}", "1"] + [f"{v:.10f}" for v in q]
            else:
                parts += [""] * 6
            if (k + 1) % a.truth_every == 0:
                q = qs[k + 1]
                parts += [f"{v:.12f}" for v in q] + [f"{v:.9e}" for v in rates[k]]
            else:
                parts += [""] * 7
            f.write(",".join(parts) + "\n")
    print(f"wrote {a.out}: {n} samples ({a.duration} s), {len(st_rows)} star-tracker solutions")


if __name__ == "__main__":
    main()
