"""The unit in closed loop with Basilisk (AVS Lab, ``pip install bsk``, 2.12.1).

:class:`UnitNav` is a Basilisk module written the way Basilisk's own Python modules are
(a ``sysModel.SysModel`` with message readers and writers). Every 5 ms it takes the
vehicle's motion (``scStateInMsg``, Basilisk's ``SCStatesMsg``), makes the unit's four FOG
increments from it (each FOG's sensitive axis from the unit's table, with turn-on bias,
bias random walk and angle random walk; or, with ``imuInMsg`` linked, from Basilisk's
``imuSensor``: its increments on the table's axes, with its own errors, so the skewed
fourth FOG is the other three's projection and the parity check sees no fault of theirs),
and the star tracker's solutions (its own model
at the table's period with a latency, or Basilisk's ``starTracker`` through
``stInMsg``), feeds them to the unit as frames, and publishes the unit's attitude and
rate as Basilisk's navigation message (``attOutMsg``, ``NavAttMsg``) for the flight
software to control on.

Backends (``backend=``): ``"in-process"``, the flight core in this process
(:class:`ssis.FlightCore`); ``"qemu"``, the firmware in QEMU in lockstep, processor in the
loop (:class:`ssis.QemuUnit`: the runner's lockstep driver; every output frame is also
compared with the in-process core, and :meth:`UnitNav.close` returns that report).

Conventions (shared/NOTES.md, measured on 2.12.1): Basilisk's β_BN is numerically the
unit's Λ (the instrument frame is the body frame B here; the table's star-tracker mount
gives the tracker's frame); its MRP set switches, so the quaternion's sign is kept
continuous; ``starTracker``'s ``timeTag`` is the instant its quaternion holds. The unit's
time is the simulation's: its step n ends at n × 5 ms; the module must run every 5 ms
from t = 0, after the spacecraft in the same task.

Faults, to see what they do to pointing: ``st_outage=(t0_s, t1_s)`` (no star-tracker
solution reaches the unit in that window) and ``fog_failure=(t_s, fog, mode)`` with mode
``"dead"`` (its frames stop) or a number, a bias step in °/h.

Until the unit reports itself aligned by the star tracker (its ``st_status`` bit; 2.1 s, 429
steps, in examples/basilisk-closed-loop), the module passes the vehicle's motion through
and counts those steps (``steps_before_aligned``): the flight software is not to control
on an unaligned unit.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any, Optional, Tuple, Union

import numpy as np

from Basilisk.architecture import messaging, sysModel  # type: ignore

from . import FlightCore, QemuUnit, Table

__all__ = ["UnitNav", "ST_ALIGNED"]

DT_S = 0.005
ARCSEC = math.pi / 180 / 3600
DEG_H = math.pi / 180 / 3600
ST_ALIGNED = 1 << 2
"""Star-tracker status bit: the attitude has been aligned by the star tracker (docs/ICD.md)."""


def _mrp2ep(s: Any) -> np.ndarray:
    s = np.asarray(s, dtype=float).reshape(3)
    n2 = float(s @ s)
    return np.concatenate(([(1 - n2) / (1 + n2)], 2 * s / (1 + n2)))


def _ep2mrp(q: np.ndarray) -> list:
    if q[0] < 0:
        q = -q
    return list(q[1:] / (1 + q[0]))


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])


def _conj(q: np.ndarray) -> np.ndarray:
    return np.array([q[0], -q[1], -q[2], -q[3]])


def _rotvec(q: np.ndarray) -> np.ndarray:
    if q[0] < 0:
        q = -q
    n = math.sqrt(q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    if n < 1e-15:
        return 2 * q[1:]
    return q[1:] * (2 * math.atan2(n, q[0]) / n)


def _qexp(v: np.ndarray) -> np.ndarray:
    a = float(np.linalg.norm(v))
    if a < 1e-12:
        return np.array([1.0, v[0] / 2, v[1] / 2, v[2] / 2])
    return np.concatenate(([math.cos(a / 2)], v * (math.sin(a / 2) / a)))


class InProcess:
    """The flight core in this process."""

    name = "in-process flight core"

    def __init__(self, table: Table) -> None:
        self.core = FlightCore(table)

    def step(self, dtheta: np.ndarray, star: Optional[Tuple[float, np.ndarray]]) -> Any:
        return self.core.step(dtheta, star)

    def counters(self) -> dict:
        return self.core.counters()


class InQemu:
    """The firmware in QEMU, lockstep."""

    name = "firmware in QEMU (lockstep)"

    def __init__(self, table: Table) -> None:
        self.unit = QemuUnit(table)
        self.report = ""

    def step(self, dtheta: np.ndarray, star: Optional[Tuple[float, np.ndarray]]) -> Any:
        return self.unit.step(dtheta, star)

    def counters(self) -> dict:
        return {}

    def close(self) -> str:
        self.report = self.report or self.unit.close()
        return self.report


class UnitNav(sysModel.SysModel):
    """The unit as a Basilisk navigation source (module docstring)."""

    def __init__(
        self,
        table: Optional[Table] = None,
        backend: Union[str, Any] = "in-process",
        arw_deg_sqrt_h: Optional[float] = None,
        rrw_deg_h_sqrt_h: Optional[float] = None,
        turn_on_bias_deg_h: float = 0.05,
        st_sigma_arcsec: Optional[float] = None,
        st_period_s: Optional[float] = None,
        st_latency_s: float = 0.05,
        st_outage: Optional[Tuple[float, float]] = None,
        fog_failure: Optional[Tuple[float, int, Union[str, float]]] = None,
        seed: int = 1,
    ) -> None:
        super().__init__()
        self.ModelTag = "ssisUnitNav"
        self.scStateInMsg = messaging.SCStatesMsgReader()
        self.stInMsg = messaging.STSensorMsgReader()
        self.imuInMsg = messaging.IMUSensorMsgReader()
        self.attOutMsg = messaging.NavAttMsg()
        self.table = table if table is not None else Table.default()
        if backend == "in-process":
            backend = InProcess(self.table)
        elif backend == "qemu":
            backend = InQemu(self.table)
        elif isinstance(backend, str):
            raise ValueError(f"backend {backend!r}: 'in-process' or 'qemu'")
        self.backend = backend
        t = self.table
        self.arw = t.get("observer.arw_deg_sqrt_h") if arw_deg_sqrt_h is None else arw_deg_sqrt_h
        self.rrw = t.get("observer.rrw_deg_h_sqrt_h") if rrw_deg_h_sqrt_h is None else rrw_deg_h_sqrt_h
        self.st_sigma = t.get("observer.st_sigma_arcsec") if st_sigma_arcsec is None else st_sigma_arcsec
        self.st_period = t.get("observer.st_period_s") if st_period_s is None else st_period_s
        self.st_latency = st_latency_s
        self.st_outage = st_outage
        self.fog_failure = fog_failure
        self.axes = np.array(t.axes())
        self.st_mount = np.array([t.get(f"st_mount_q[{k}]") for k in range(4)])
        self.rng = np.random.default_rng(seed)
        self.bias_rad_s = self.rng.normal(0, turn_on_bias_deg_h * DEG_H, 4)
        self.steps_before_aligned = 0
        self.last = None
        self._q_prev: Optional[np.ndarray] = None
        self._pending: deque = deque()
        self._next_st_s = 0.0
        self._st_seen_ns = -1

    def Reset(self, CurrentSimNanos: int) -> None:
        if not self.scStateInMsg.isLinked():
            self.bskLogger.bskLog(0, "UnitNav.scStateInMsg is not linked")  # BSK_ERROR
        self.attOutMsg.write(messaging.NavAttMsgPayload(), CurrentSimNanos, self.moduleID)

    def _truth(self) -> Tuple[np.ndarray, np.ndarray]:
        s = self.scStateInMsg()
        q = _mrp2ep(s.sigma_BN)
        if self._q_prev is not None and float(q @ self._q_prev) < 0:
            q = -q
        return q, np.asarray(s.omega_BN_B, dtype=float)

    def _star_due(self, t_s: float, q_true: np.ndarray) -> Optional[Tuple[float, np.ndarray]]:
        """The star-tracker solution arriving in this step (its tag, Λ*), if any."""
        if self.stInMsg.isLinked():
            if self.stInMsg.isWritten() and self.stInMsg.timeWritten() != self._st_seen_ns:
                self._st_seen_ns = self.stInMsg.timeWritten()
                m = self.stInMsg()
                q = np.asarray(m.qInrtl2Case, dtype=float)
                self._pending.append((m.timeTag * 1e-9, q if q[0] >= 0 else -q))
        elif t_s + 1e-9 >= self._next_st_s:
            self._next_st_s += self.st_period
            noise = _qexp(self.rng.normal(0, self.st_sigma * ARCSEC, 3))
            q = _qmul(_qmul(q_true, _conj(self.st_mount)), noise)
            self._pending.append((t_s, q if q[0] >= 0 else -q))
        if self._pending and self._pending[0][0] + self.st_latency <= t_s + 1e-9:
            tag, q = self._pending.popleft()
            if self.st_outage is not None and self.st_outage[0] <= tag < self.st_outage[1]:
                return None
            return (tag, q) if tag > 0 else None
        return None

    def UpdateState(self, CurrentSimNanos: int) -> None:
        t_s = CurrentSimNanos * 1e-9
        q, w = self._truth()
        star = self._star_due(t_s, q)
        if self._q_prev is None:
            self._q_prev = q
            self._publish(CurrentSimNanos, q, w)
            return
        body = _rotvec(_qmul(_conj(self._q_prev), q))
        self._q_prev = q
        if self.imuInMsg.isLinked():
            # Basilisk's IMU: its increment over (t - Δt, t] in its platform frame (taken as
            # the body frame), with its own errors; the fourth FOG is its projection.
            d = self.axes @ np.asarray(self.imuInMsg().DRFramePlatform, dtype=float)
        else:
            sv = self.arw * math.pi / 180 / 60 * math.sqrt(DT_S)
            self.bias_rad_s = self.bias_rad_s + self.rng.normal(0, self.rrw * DEG_H / 60 * math.sqrt(DT_S), 4)
            d = self.axes @ body + self.bias_rad_s * DT_S + self.rng.normal(0, sv, 4)
        if self.fog_failure is not None and t_s >= self.fog_failure[0]:
            _, i, mode = self.fog_failure
            d[i] = math.nan if mode == "dead" else d[i] + float(mode) * DEG_H * DT_S
        out = self.backend.step(d, star)
        self.last = out
        if not out.st_status & ST_ALIGNED:
            self.steps_before_aligned += 1
            self._publish(CurrentSimNanos, q, w)
            return
        self._publish(CurrentSimNanos, np.asarray(out.q), np.asarray(out.rate_rad_s))

    def close(self) -> str:
        """Ends the backend's run; the QEMU backend's report (empty in-process)."""
        close = getattr(self.backend, "close", None)
        return close() if close is not None else ""

    def _publish(self, nanos: int, q: np.ndarray, w: np.ndarray) -> None:
        p = messaging.NavAttMsgPayload()
        p.timeTag = nanos * 1e-9
        p.sigma_BN = _ep2mrp(q)
        p.omega_BN_B = list(w)
        self.attOutMsg.write(p, nanos, self.moduleID)
