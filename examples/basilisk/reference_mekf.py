#!/usr/bin/env python3
"""A reference estimator on a recorded log: a textbook 6-state multiplicative extended
Kalman filter (attitude error, gyro drift; Lefferts, Markley & Shuster 1982) on the same
FOG increments and star-tracker solutions the unit gets, scored against the log's truth
the way `ssis-sim replay` scores the unit (3 sigma = |mean| + 3 std per axis after
settling, every row with truth).

    python3 reference_mekf.py leo-nadir-280s.csv --settle 60

Noise figures default to the example's table (table.toml): FOG ARW 0.05 deg/sqrt(h),
bias walk 0.01 deg/h/sqrt(h), tracker 20/3 arcsec 1 sigma per axis.
"""
import argparse
import math

import numpy as np

DT = 0.005
ARCSEC = math.pi / 180 / 3600
S = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [-1 / math.sqrt(3)] * 3])
PINV = np.linalg.pinv(S)  # body increment from the four FOGs (least squares)


def qmul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def qexp(v):
    a = np.linalg.norm(v)
    if a < 1e-15:
        return np.array([1.0, *(v / 2)])
    return np.array([math.cos(a / 2), *(v * math.sin(a / 2) / a)])


def rotvec(q):
    if q[0] < 0:
        q = -q
    n = np.linalg.norm(q[1:])
    return q[1:] * (2 * math.atan2(n, q[0]) / n) if n > 1e-15 else 2 * q[1:]


def conj(q):
    return np.array([q[0], -q[1], -q[2], -q[3]])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("log")
    ap.add_argument("--settle", type=float, default=60.0)
    ap.add_argument("--arw", type=float, default=0.05)
    ap.add_argument("--rrw", type=float, default=0.01)
    ap.add_argument("--st-sigma", type=float, default=20.0 / 3)
    a = ap.parse_args()

    rows = [l.rstrip("\n").split(",") for l in open(a.log) if not l.startswith("#") and l.strip()]
    h, rows = rows[0], rows[1:]
    col = {n: i for i, n in enumerate(h)}
    t0 = float(rows[0][col["t_s"]]) - DT
    sv2 = (a.arw * math.pi / 180 / 60) ** 2 * (PINV @ PINV.T)[0, 0]
    su2 = (a.rrw * math.pi / 180 / 3600 / 60) ** 2
    r = (a.st_sigma * ARCSEC) ** 2
    q = None
    b = np.zeros(3)
    P = np.diag([r] * 3 + [(0.1 * math.pi / 180 / 3600) ** 2] * 3)
    Q = np.diag([sv2 * DT] * 3 + [su2 * DT] * 3)
    pending = []  # (tag, q_st) awaiting the step that ends at or after the tag
    errs = []
    prev_body = np.zeros(3)
    for row in rows:
        t = float(row[col["t_s"]]) - t0
        m = np.array([float(row[col[f"fog{i}_dtheta_rad"]]) for i in range(4)])
        body = PINV @ m - b * DT
        if row[col["st_t_s"]]:
            pending.append((float(row[col["st_t_s"]]) - t0, np.array([float(row[col[f"st_q{k}"]]) for k in range(4)])))
        if q is None:
            if not pending:
                continue
            q = pending.pop(0)[1]  # aligned on the first solution
        # Propagate over the step (two-sample coning term, as the unit does).
        phi = body + np.cross(prev_body, body) / 12
        prev_body = body
        q = qmul(q, qexp(phi))
        q /= np.linalg.norm(q)
        F = np.eye(6)
        F[0:3, 0:3] -= np.array([[0, -phi[2], phi[1]], [phi[2], 0, -phi[0]], [-phi[1], phi[0], 0]])
        F[0:3, 3:6] = -np.eye(3) * DT
        P = F @ P @ F.T + Q
        # Updates at their tags: the attitude at the tag from the step's increment.
        while pending and pending[0][0] <= t + 1e-9:
            tag, q_st = pending.pop(0)
            back = (t - tag) / DT
            q_tag = qmul(q, qexp(-phi * back))
            e = rotvec(qmul(conj(q_tag), q_st))
            Hm = np.hstack([np.eye(3), np.zeros((3, 3))])
            K = P @ Hm.T @ np.linalg.inv(Hm @ P @ Hm.T + r * np.eye(3))
            dx = K @ e
            q = qmul(q, qexp(dx[0:3]))
            q /= np.linalg.norm(q)
            b = b + dx[3:6]
            P = (np.eye(6) - K @ Hm) @ P
        if row[col["true_q0"]] and t >= a.settle:
            qt = np.array([float(row[col[f"true_q{k}"]]) for k in range(4)])
            errs.append(rotvec(qmul(conj(qt), q)) / ARCSEC)
    e = np.array(errs)
    three = np.abs(e.mean(0)) + 3 * e.std(0)
    print(f"reference MEKF: attitude error 3 sigma after {a.settle:.0f} s: "
          f"{three[0]:.2f} / {three[1]:.2f} / {three[2]:.2f} arcsec ({len(e)} rows)")


if __name__ == "__main__":
    main()
