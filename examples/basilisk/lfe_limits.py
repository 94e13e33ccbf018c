"""Attitude error limits with a star tracker's low-frequency error (LFE), and what a filter
with the other model does (BENCHMARKS.md, "Star tracker with a low-frequency error").

Per axis, the steady state of the Kalman filter of x = (attitude, drift, LFE), the LFE a
first-order Gauss-Markov process seen with the attitude (H = [1 0 1]), or of the white
filter (x = (attitude, drift), H = [1 0]); then the true error covariance of either
filter's steady gains on data with or without the LFE (the joint state: attitude and
drift errors, the true LFE and the filter's LFE estimate). Scored as the replay scores:
3 sigma, averaged over the update period, every age moved by the tracker's latency.
Needs numpy.

    python3 lfe_limits.py
"""
import numpy as np

AS = np.pi / 180 / 3600


def limits(arw, rrw, st_sigma, period, lfe_sigma, lfe_tau, latency=0.05, dt=0.005, n=5 / 6):
    sv2 = (arw * np.pi / 180 / 60) ** 2 * n
    su2 = (rrw * np.pi / 180 / 3600 / 60) ** 2
    r, sc2 = (st_sigma * AS) ** 2, (lfe_sigma * AS) ** 2

    def q_gyro(h):
        return np.array([[sv2 * h + su2 * h**3 / 3, -su2 * h * h / 2], [-su2 * h * h / 2, su2 * h]])

    def gains(model_lfe):
        phi = np.exp(-period / lfe_tau) if model_lfe else 0.0
        f = np.array([[1, -period, 0], [0, 1, 0], [0, 0, phi]])
        q = np.zeros((3, 3))
        q[:2, :2] = q_gyro(period)
        q[2, 2] = sc2 * (1 - phi * phi) if model_lfe else 0.0
        h = np.array([1.0, 0, 1.0 if model_lfe else 0.0])
        p = np.diag([r + sc2, su2 * 1e4, sc2 if model_lfe else 0.0])
        for _ in range(400000):
            m = f @ p @ f.T + q
            s = h @ m @ h + r
            k = m @ h / s
            nxt = m - np.outer(k, k) * s
            if np.abs(nxt - p).max() < 1e-32:
                break
            p = nxt
        return k

    def actual(model_lfe, data_lfe):
        ka, kb, kc = gains(model_lfe)

        def prop(z, h):
            phi = np.exp(-h / lfe_tau)
            f = np.diag([1.0, 1.0, phi, phi if model_lfe else 0.0])
            f[0, 1] = -h
            q = np.zeros((4, 4))
            q[:2, :2] = q_gyro(h)
            q[2, 2] = sc2 * (1 - phi * phi) if data_lfe else 0.0
            return f @ z @ f.T + q

        g = np.array([-ka, -kb, 0.0, kc])
        hz = np.array([1.0, 0.0, 1.0 if data_lfe else 0.0, -1.0])
        a = np.eye(4) + np.outer(g, hz)

        z = np.diag([r, su2 * 1e4, sc2 if data_lfe else 0.0, 0.0])
        for _ in range(400000):
            nxt = a @ prop(z, period) @ a.T + np.outer(g, g) * r
            if np.abs(nxt - z).max() < 1e-32:
                break
            z = nxt
        z = nxt
        for _ in range(int(round(latency / dt))):
            z = prop(z, dt)
        total, steps = 0.0, int(round(period / dt))
        for _ in range(steps):
            total += z[0, 0]
            z = prop(z, dt)
        return 3 * np.sqrt(total / steps) / AS

    return {f"{'LFE' if m else 'white'} filter, {'LFE' if d else 'white'} data": round(actual(m, d), 2)
            for m in (False, True) for d in (False, True)}


if __name__ == "__main__":
    print("the paper's sensors:", limits(0.005, 0.01, 20 / 3, 0.25, 4.0, 300.0))
    print("examples/basilisk:  ", limits(0.05, 0.01, 20 / 3, 0.1, 4.0, 300.0))
