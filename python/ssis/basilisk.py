"""The unit in closed loop with Basilisk (AVS Lab, ``pip install bsk``, 2.12.1).

:class:`UnitNav` is a Basilisk module written the way Basilisk's own Python modules are
(a ``sysModel.SysModel`` with message readers and writers). Every 5 ms it takes the
vehicle's motion (``scStateInMsg``, Basilisk's ``SCStatesMsg``), makes the unit's four FOG
increments from it (each FOG's sensitive axis from the unit's table, with turn-on bias,
bias random walk and angle random walk; or, with ``imuInMsg`` linked, from Basilisk's
``imuSensor``: its increments on the table's axes, with its own errors, so the skewed
fourth FOG is the other three's projection and the parity check sees no fault of theirs),
and the star tracker's solutions (the simulator's model
at the table's period with a latency, or Basilisk's ``starTracker`` through
``stInMsg``), feeds them to the unit as frames, and publishes the unit's attitude and
rate as Basilisk's navigation message (``attOutMsg``, ``NavAttMsg``) for the flight
software to control on.

Backends (``backend=``): ``"in-process"``, the flight core in this process
(:class:`ssis.FlightCore`); ``"qemu"``, the firmware in QEMU in lockstep, processor in the
loop (:class:`ssis.QemuUnit`: the runner's lockstep driver; every output frame is also
compared with the in-process core, and :meth:`UnitNav.close` returns that report).

Conventions (docs/REFERENCES.md, measured on 2.12.1): Basilisk's β_BN is numerically the
unit's Λ (the instrument frame is the body frame B here; the table's star-tracker mount
gives the tracker's frame); its MRP set switches, so the quaternion's sign is kept
continuous; ``starTracker``'s ``timeTag`` is the instant its quaternion holds. The unit's
time is the simulation's: its step n ends at n × 5 ms; the module must run every 5 ms
from t = 0, after the spacecraft in the same task.

Faults, to see what they do to pointing: ``st_outage=(t0_s, t1_s)`` (no star-tracker
solution reaches the unit in that window) and ``fog_failure=(t_s, fog, mode)`` with mode
``"dead"`` (its frames stop) or a number, a bias step in °/h.

The sensors are the simulator's (``ssis._ssis.Sensors``: ``ssis_sim::sensors``, the FOG
model of ``fog.rs`` and the star tracker of ``star.rs`` on one random stream), so a seed
gives the frames ``ssis-sim`` would send for the same truth; the quaternion products and
rotation vectors are the flight code's (``ssis::math``), the MRP conversions Basilisk's.

**The unit's step.** The module must run every 5 ms (the unit's step) from t = 0: on any
other task period it raises ``ValueError`` naming the period (Basilisk reports it as a
``RuntimeError`` from ``ExecuteSimulation``; the module keeps it in :attr:`UnitNav.error`).

**Truth only before the first alignment.** Until the unit first reports itself aligned by
the star tracker (its ``st_status`` bit; 2.1 s in examples/basilisk-closed-loop), the
module passes the vehicle's motion through and counts those steps
(``steps_before_aligned``, ``first_aligned_s``): the flight software is not to control on
an unaligned unit. From then on it publishes the unit's output whatever the unit's
status. Every later loss of status (ALIGNED, or the observer's CONVERGED flag) is
reported: a :class:`UnitStatusWarning`, a count (``status_losses``, by kind in
``losses``), and with ``strict=True`` a :class:`UnitStatusLost` raised instead; a status
regained counts in ``realignments`` (ALIGNED) and ``reconvergences`` (CONVERGED).
"""

from __future__ import annotations

import math
import time
import warnings
from collections import deque
from typing import Any, List, Optional, Tuple, Union

import numpy as np

from Basilisk.architecture import bskLogging, messaging, sysModel  # type: ignore
from Basilisk.utilities import RigidBodyKinematics as rbk  # type: ignore

from . import FlightCore, QemuUnit, Table, _ssis

__all__ = ["UnitNav", "UnitStatusLost", "UnitStatusWarning", "ST_ALIGNED", "CONVERGED", "Leo", "fly_leo", "slew_events"]

DT_S = 0.005
STEP_NS = 5_000_000
DEG_H = math.pi / 180 / 3600
ST_ALIGNED = 1 << 2
"""Star-tracker status bit: the attitude has been aligned by the star tracker (docs/ICD.md)."""
CONVERGED = 1 << 2
"""Flag bit: the observer has converged (docs/ICD.md)."""


class UnitStatusWarning(UserWarning):
    """The unit lost a status (ALIGNED or CONVERGED) after its first alignment; the module
    goes on publishing its output."""


class UnitStatusLost(RuntimeError):
    """Raised instead of :class:`UnitStatusWarning` by a ``strict`` :class:`UnitNav`."""


def _mrp2ep(s: Any) -> np.ndarray:
    return np.asarray(rbk.MRP2EP(np.asarray(s, dtype=float).reshape(3)), dtype=float)


def _ep2mrp(q: np.ndarray) -> list:
    return list(rbk.EP2MRP(np.asarray(q, dtype=float)))


class InProcess:
    """The flight core in this process."""

    name = "in-process flight core"

    def __init__(self, table: Table) -> None:
        self.core = FlightCore(table)

    def step(self, dtheta: np.ndarray, star: Optional[Tuple[float, np.ndarray]],
             temperature_degc: Optional[np.ndarray] = None, star_valid: bool = True) -> Any:
        return self.core.step(dtheta, star, temperature_degc, star_valid)

    def counters(self) -> dict:
        return self.core.counters()


class InQemu:
    """The firmware in QEMU, lockstep."""

    name = "firmware in QEMU (lockstep)"

    def __init__(self, table: Table) -> None:
        self.unit = QemuUnit(table)
        self.report = ""

    def step(self, dtheta: np.ndarray, star: Optional[Tuple[float, np.ndarray]],
             temperature_degc: Optional[np.ndarray] = None, star_valid: bool = True) -> Any:
        return self.unit.step(dtheta, star, temperature_degc, star_valid)

    def counters(self) -> dict:
        return {}

    def close(self) -> str:
        self.report = self.report or self.unit.close()
        return self.report


class UnitNav(sysModel.SysModel):
    """The unit as a Basilisk navigation source (module docstring).

    ``truth``: the table of the sensors' true errors (the FOGs' bias, scale factor and
    misalignment, the tracker's mount), when they differ from the unit's ``table`` (a
    calibration that is not perfect, e.g. dispersed in a Monte Carlo campaign).

    A custom ``backend`` is an object with ``step(fog_dtheta_rad, star, temperature_degc,
    star_valid)`` returning what :meth:`ssis.FlightCore.step` does, and ``counters()``.
    """

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
        strict: bool = False,
        truth: Optional[Table] = None,
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
        st_sigma = t.get("observer.st_sigma_arcsec") if st_sigma_arcsec is None else st_sigma_arcsec
        self.st_latency = st_latency_s
        self.st_outage = st_outage
        self.fog_failure = fog_failure
        self.strict = strict
        self.axes = np.array(t.axes())
        # The simulator's FOGs (turn-on bias 1σ given, 3σ taken) and star tracker; made
        # again in Reset, when it is known whether Basilisk's tracker is linked instead.
        self._sensor_args = dict(
            table=t if truth is None else truth, seed=seed, arw_deg_sqrt_h=arw_deg_sqrt_h, rrw_deg_h_sqrt_h=rrw_deg_h_sqrt_h,
            turn_on_bias_3sigma_deg_h=3 * turn_on_bias_deg_h, st_sigma_3sigma_arcsec=3 * st_sigma,
            st_period_s=st_period_s, st_latency_s=st_latency_s,
            st_outages=[tuple(st_outage)] if st_outage is not None else [],
        )
        self.sensors = _ssis.Sensors(**self._sensor_args)
        self.error: Optional[Exception] = None
        """The error the module raised in the simulation (Basilisk re-raises it as RuntimeError)."""
        self._start()

    def _start(self) -> None:
        self.last: Any = None
        self.steps_before_aligned = 0
        """Steps flown on truth before the unit's first alignment."""
        self.first_aligned_s: Optional[float] = None
        """When the unit first reported ALIGNED, s (None: never)."""
        self.status_losses = 0
        """Losses of ALIGNED or CONVERGED after the first alignment."""
        self.losses: List[Tuple[float, str]] = []
        """Each loss: (t_s, "aligned" or "converged")."""
        self.realignments = 0
        """ALIGNED regained after a loss."""
        self.reconvergences = 0
        """CONVERGED regained after a loss."""
        self._had = {"aligned": False, "converged": False}
        self._q_prev: Optional[np.ndarray] = None
        self._pending: deque = deque()
        self._arrived: deque = deque()
        self._st_seen_ns = -1
        self._last_ns: Optional[int] = None

    def Reset(self, CurrentSimNanos: int) -> None:
        if not self.scStateInMsg.isLinked():
            self.bskLogger.bskLog(bskLogging.BSK_ERROR, "UnitNav.scStateInMsg is not linked")
        self._start()
        self.sensors = _ssis.Sensors(**self._sensor_args, star_tracker=not self.stInMsg.isLinked())
        self.attOutMsg.write(messaging.NavAttMsgPayload(), CurrentSimNanos, self.moduleID)

    def _truth(self) -> Tuple[np.ndarray, np.ndarray]:
        s = self.scStateInMsg()
        q = _mrp2ep(s.sigma_BN)
        if self._q_prev is not None and float(q @ self._q_prev) < 0:
            q = -q
        return q, np.asarray(s.omega_BN_B, dtype=float)

    def _basilisk_star(self, t_s: float) -> Optional[Tuple[float, np.ndarray, bool]]:
        """The solution of Basilisk's tracker arriving in this step (its tag, Λ*, valid), if any."""
        if self.stInMsg.isWritten() and self.stInMsg.timeWritten() != self._st_seen_ns:
            self._st_seen_ns = self.stInMsg.timeWritten()
            m = self.stInMsg()
            q = np.asarray(m.qInrtl2Case, dtype=float)
            self._pending.append((m.timeTag * 1e-9, q if q[0] >= 0 else -q))
        if self._pending and self._pending[0][0] + self.st_latency <= t_s + 1e-9:
            tag, q = self._pending.popleft()
            if self.st_outage is not None and self.st_outage[0] <= tag < self.st_outage[1]:
                return None
            return (tag, q, True) if tag > 0 else None
        return None

    def _check_period(self, nanos: int) -> None:
        """Refuses any period but the unit's step (and a start later than t = 0)."""
        last, self._last_ns = self._last_ns, nanos
        if last is None and nanos != 0:
            msg = (f"UnitNav first ran at t = {nanos * 1e-9:g} s: the unit's clock is the simulation's "
                   "(its step n ends at n × 5 ms), so it must run from t = 0")
        elif last is not None and nanos - last != STEP_NS:
            msg = (f"UnitNav runs every {(nanos - last) * 1e-6:g} ms: the unit steps every "
                   f"{STEP_NS * 1e-6:g} ms (its clock is the simulation's); put it on a "
                   "macros.sec2nano(0.005) task")
        else:
            return
        self.error = ValueError(msg)
        self.bskLogger.bskLog(bskLogging.BSK_ERROR, msg)
        raise self.error

    def UpdateState(self, CurrentSimNanos: int) -> None:
        self._check_period(CurrentSimNanos)
        t_s = CurrentSimNanos * 1e-9
        q, w = self._truth()
        if self._q_prev is None:
            self._q_prev = q
            self._publish(CurrentSimNanos, q, w)
            return
        body = _ssis.rotation_vector(_ssis.quat_mul(_ssis.quat_conj(self._q_prev), q))
        self._q_prev = q
        s = self.sensors.step(body, q, w)
        temps: Optional[np.ndarray] = None
        if self.imuInMsg.isLinked():
            # Basilisk's IMU: its increment over (t - Δt, t] in its platform frame (taken as
            # the body frame), with its own errors; the fourth FOG is its projection.
            d = self.axes @ np.asarray(self.imuInMsg().DRFramePlatform, dtype=float)
        else:
            d, temps = np.array(s["fog_dtheta_rad"]), s["temperature_degc"]
        if self.stInMsg.isLinked():
            star = self._basilisk_star(t_s)
        else:
            self._arrived.extend(s["stars"])
            star = self._arrived.popleft() if self._arrived else None
        if self.fog_failure is not None and t_s >= self.fog_failure[0]:
            _, i, mode = self.fog_failure
            d[i] = math.nan if mode == "dead" else d[i] + float(mode) * DEG_H * DT_S
        valid = True if star is None else bool(star[2])
        out = self.backend.step(d, None if star is None else (star[0], star[1]), temps, valid)
        self.last = out
        aligned = bool(out.st_status & ST_ALIGNED)
        if self.first_aligned_s is None:
            if not aligned:
                self.steps_before_aligned += 1
                self._publish(CurrentSimNanos, q, w)
                return
            self.first_aligned_s = t_s
            self.bskLogger.bskLog(bskLogging.BSK_INFORMATION, (
                f"UnitNav: the unit aligned by the star tracker at {t_s:.3f} s; truth was published for "
                f"the {self.steps_before_aligned} steps before, the unit's output from now on"))
        self._watch(t_s, {"aligned": aligned, "converged": bool(out.flags & CONVERGED)})
        self._publish(CurrentSimNanos, np.asarray(out.q), np.asarray(out.rate_rad_s))

    def _watch(self, t_s: float, now: dict) -> None:
        """Counts each status the unit loses (a warning, or raised when strict) and regains."""
        for kind, on in now.items():
            had, self._had[kind] = self._had[kind], on
            if on and not had and any(k == kind for _, k in self.losses):
                if kind == "aligned":
                    self.realignments += 1
                else:
                    self.reconvergences += 1
            if had and not on:
                self.status_losses += 1
                self.losses.append((t_s, kind))
                msg = (f"UnitNav: the unit lost {kind.upper()} at t = {t_s:.3f} s (loss {self.status_losses} "
                       f"after its first alignment at {self.first_aligned_s:.3f} s); its output is still published")
                if self.strict:
                    self.error = UnitStatusLost(msg)
                    raise self.error
                warnings.warn(msg, UnitStatusWarning, stacklevel=2)

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


# ---------------------------------------------------------------------------------------
# The LEO spacecraft of examples/basilisk-closed-loop, flown on a navigation source.

ARCSEC_PER_RAD = 180 / math.pi * 3600
INERTIA_KG_M2 = [900.0, 0.0, 0.0, 0.0, 800.0, 0.0, 0.0, 0.0, 600.0]
"""The vehicle's inertia about its centre of mass, row-major, kg m²."""


def slew_events(duration_s: float) -> list:
    """(t_s, principal rotation vector or None = back to nadir) in time order."""
    ev: list = []
    for p in range(int(math.ceil(duration_s / 180.0))):
        b = 180.0 * p
        if p > 0:
            ev.append((b, None))
        ev += [(b + 40.0, np.array([1.0, 0, 0]) * math.radians(15)),
               (b + 110.0, np.array([0, 0.6, 0.8]) * math.radians(-20)),
               (b + 145.0, np.array([-1.0, 0, 0]) * math.radians(15))]
    return [e for e in ev if e[0] < duration_s]


class Leo:
    """The LEO spacecraft in ``sim``'s task ``task`` (Basilisk: ``spacecraft``, 750 kg,
    inertia :data:`INERTIA_KG_M2`, a 500-km circular orbit at 51.6°, point-mass Earth,
    starting on the Hill frame and turning with it) holding nadir (``hillPoint``) under
    ``mrpFeedback`` (K = 36, P = 160) commanding ``extForceTorque``; the flight software
    navigates on ``unit`` (a :class:`UnitNav`, after the spacecraft) or, with ``None``, on
    truth (``simpleNav`` without noise). Within the task, higher priority runs first:
    dynamics, then the sensors, then the flight software on what they published at this
    instant. :meth:`fly` steps the reference offset at each of :func:`slew_events`.

    ``sc`` (the spacecraft), ``truth_nav`` (``simpleNav`` on truth), ``att_msg`` (the
    navigation message the flight software flies on), ``hill`` and ``err`` (its guidance)
    are there to link more modules to."""

    def __init__(self, sim: Any, task: str, unit: Optional["UnitNav"] = None) -> None:
        from Basilisk.fswAlgorithms import attTrackingError, hillPoint, mrpFeedback  # type: ignore
        from Basilisk.simulation import extForceTorque, simpleNav, spacecraft  # type: ignore
        from Basilisk.utilities import orbitalMotion, simIncludeGravBody  # type: ignore

        self.sim, self.unit = sim, unit
        sc = spacecraft.Spacecraft()
        sc.ModelTag = "leo"
        sc.hub.mHub = 750.0
        inertia = INERTIA_KG_M2
        sc.hub.IHubPntBc_B = [inertia[0:3], inertia[3:6], inertia[6:9]]
        grav = simIncludeGravBody.gravBodyFactory()
        earth = grav.createEarth()
        earth.isCentralBody = True
        grav.addBodiesTo(sc)
        oe = orbitalMotion.ClassicElements()
        oe.a, oe.e, oe.i = earth.radEquator + 500e3, 0.0, math.radians(51.6)
        oe.Omega, oe.omega, oe.f = math.radians(48.2), 0.0, math.radians(85.3)
        r_n, v_n = orbitalMotion.elem2rv(earth.mu, oe)
        sc.hub.r_CN_NInit, sc.hub.v_CN_NInit = r_n, v_n
        r_hat = np.asarray(r_n) / np.linalg.norm(r_n)
        h_hat = np.cross(r_n, v_n) / np.linalg.norm(np.cross(r_n, v_n))
        sc.hub.sigma_BNInit = [[c] for c in rbk.C2MRP(np.array([r_hat, np.cross(h_hat, r_hat), h_hat]))]
        sc.hub.omega_BN_BInit = [[0.0], [0.0], [np.linalg.norm(np.cross(r_n, v_n)) / np.dot(r_n, r_n)]]
        sim.AddModelToTask(task, sc, 100)
        self.sc = sc
        self.truth_nav = simpleNav.SimpleNav()
        self.truth_nav.scStateInMsg.subscribeTo(sc.scStateOutMsg)
        sim.AddModelToTask(task, self.truth_nav, 90)
        if unit is None:
            self.att_msg = self.truth_nav.attOutMsg
        else:
            unit.scStateInMsg.subscribeTo(sc.scStateOutMsg)
            sim.AddModelToTask(task, unit, 80)
            self.att_msg = unit.attOutMsg
        self.hill = hillPoint.hillPoint()
        self.hill.transNavInMsg.subscribeTo(self.truth_nav.transOutMsg)
        sim.AddModelToTask(task, self.hill, 70)
        self.err = attTrackingError.attTrackingError()
        self.err.attRefInMsg.subscribeTo(self.hill.attRefOutMsg)
        self.err.attNavInMsg.subscribeTo(self.att_msg)
        sim.AddModelToTask(task, self.err, 60)
        self._errs = [self.err]
        vc = messaging.VehicleConfigMsgPayload()
        vc.ISCPntB_B = inertia
        self._vc_msg = messaging.VehicleConfigMsg().write(vc)
        ctl = mrpFeedback.mrpFeedback()
        ctl.K, ctl.P, ctl.Ki = 36.0, 160.0, -1.0
        ctl.guidInMsg.subscribeTo(self.err.attGuidOutMsg)
        ctl.vehConfigInMsg.subscribeTo(self._vc_msg)
        sim.AddModelToTask(task, ctl, 50)
        ext = extForceTorque.ExtForceTorque()
        ext.cmdTorqueInMsg.subscribeTo(ctl.cmdTorqueOutMsg)
        sc.addDynamicEffector(ext)
        sim.AddModelToTask(task, ext, 40)
        self._ctl, self._ext, self._task = ctl, ext, task

    def true_pointing(self) -> Any:
        """An ``attTrackingError`` of the true attitude against the same reference (offsets
        and all), after the flight software's in the task: the true pointing error, for a
        score only."""
        from Basilisk.fswAlgorithms import attTrackingError  # type: ignore

        meas = attTrackingError.attTrackingError()
        meas.attRefInMsg.subscribeTo(self.hill.attRefOutMsg)
        meas.attNavInMsg.subscribeTo(self.truth_nav.attOutMsg)
        self.sim.AddModelToTask(self._task, meas, 60)
        self._errs.append(meas)
        return meas

    def fly(self, duration_s: float) -> None:
        """Runs the initialised simulation to ``duration_s``, stepping the reference offset
        (σ_R0R, each slew composed with the offset before) at each of :func:`slew_events`."""
        from Basilisk.utilities import macros  # type: ignore

        def run_to(t_s: float) -> None:
            self.sim.ConfigureStopTime(macros.sec2nano(t_s))
            try:
                self.sim.ExecuteSimulation()
            except RuntimeError:
                # Basilisk reports a Python module's exception as its own; UnitNav keeps it
                if self.unit is not None and self.unit.error is not None:
                    raise self.unit.error from None
                raise

        offset = np.zeros(3)
        for t0, prv in slew_events(duration_s):
            run_to(t0)
            offset = np.zeros(3) if prv is None else np.asarray(rbk.addMRP(offset, rbk.PRV2MRP(prv)))
            for e in self._errs:
                e.sigma_R0R = list(offset)
        run_to(duration_s)


def fly_leo(unit: Optional["UnitNav"], duration_s: float, task_ms: float = DT_S * 1e3) -> dict:
    """One flight of the LEO spacecraft (:class:`Leo`) with the slews of
    :func:`slew_events`, on a task of ``task_ms``.

    Returns ``t_s``, ``pointing_arcsec`` (the true attitude against the reference, per
    axis, small-angle), ``nav_err_arcsec`` (the navigation message against truth, per
    axis) and ``wall_s``."""
    from Basilisk.utilities import SimulationBaseClass, macros  # type: ignore

    sim = SimulationBaseClass.SimBaseClass()
    proc = sim.CreateNewProcess("p")
    proc.addTask(sim.CreateNewTask("t", macros.sec2nano(task_ms * 1e-3)))
    leo = Leo(sim, "t", unit)
    meas = leo.true_pointing()
    rec = meas.attGuidOutMsg.recorder()
    sim.AddModelToTask("t", rec)
    st_rec = leo.truth_nav.attOutMsg.recorder()
    nav_rec = leo.att_msg.recorder()
    sim.AddModelToTask("t", st_rec)
    sim.AddModelToTask("t", nav_rec)
    sim.InitializeSimulation()
    wall = time.perf_counter()
    leo.fly(duration_s)
    wall = time.perf_counter() - wall
    t = np.asarray(rec.times()) * 1e-9
    point = 4 * np.arctan(np.asarray(rec.sigma_BR)) * ARCSEC_PER_RAD  # small-angle per axis
    nav_err = np.array([rbk.subMRP(n, s) for n, s in zip(nav_rec.sigma_BN, st_rec.sigma_BN)]) * 4 * ARCSEC_PER_RAD
    return {"t_s": t, "pointing_arcsec": point, "nav_err_arcsec": nav_err, "wall_s": wall}
