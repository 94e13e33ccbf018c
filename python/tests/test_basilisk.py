"""ssis.basilisk and the QEMU backend: the module publishes what the unit output, and the
firmware in QEMU outputs what the in-process core does on the same steps."""

import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

import ssis

from test_replay_core import _read_log


def _qemu_or_skip():
    if shutil.which("qemu-system-arm") is None:
        if os.environ.get("SSIS_REQUIRE_QEMU") == "1":
            pytest.fail("qemu-system-arm is not installed")
        pytest.skip("qemu-system-arm is not installed")


def test_qemu_unit_outputs_what_the_core_does(short_log, root):
    """Outputs and events: FOG 3 drifts off by 2 mrad/s from step 300, so the parity check
    raises an alarm and then isolates it (events both backends must report alike)."""
    _qemu_or_skip()
    table = ssis.Table.read(root / "examples/basilisk/table.toml")
    c = _read_log(short_log)
    t0 = c["t_s"][0] - 0.005
    n = 600
    core = ssis.FlightCore(table)
    events = ([], [])
    with ssis.QemuUnit(table, steps=n) as fw:
        for k in range(n):
            d = [c[f"fog{i}_dtheta_rad"][k] for i in range(4)]
            if k >= 300:
                d[2] += 1e-5
            star = None
            if not math.isnan(c["st_t_s"][k]):
                sq = np.array([c[f"st_q{i}"][k] for i in range(4)])
                star = (c["st_t_s"][k] - t0, sq / np.linalg.norm(sq))
            a, b = core.step(d, star), fw.step(d, star)
            counts = np.clip(np.round(a.q * 2**31), -(2**31), 2**31 - 1)
            assert np.array_equal(counts, np.round(b.q * 2**31)), k
            # OUTPUT_DROPPED (bit 4) masked as the runner masks it: the board's TX ring may
            # drop a frame on its own tick before lockstep, while QEMU starts on a busy host
            assert (a.flags & ~16, a.st_status, a.fog_health) == (b.flags & ~16, b.st_status, b.fog_health), k
            assert a.time_s == b.time_s
            # each step's events with that step, not a step later
            assert a.events == b.events, k
            events[0].extend(a.events)
            events[1].extend(b.events)
        report = fw.close()
    assert f"host/QEMU equivalence: {n} output frames identical, 0 different" in report
    assert "host/QEMU events: identical" in report
    names = [e["event"] for e in events[1]]
    assert "parity_alarm" in names and "isolated" in names, names
    isolated = next(e for e in events[1] if e["event"] == "isolated")
    assert isolated["a"] == 3 and isolated["details"] == "FOG3 named by the star tracker during a parity alarm"


def _fly_unit_nav(root, basilisk_star_tracker, basilisk_imu=False):
    pytest.importorskip("Basilisk")
    from Basilisk.architecture import messaging
    from Basilisk.simulation import imuSensor, starTracker
    from Basilisk.utilities import SimulationBaseClass, macros

    from ssis.basilisk import ST_ALIGNED, UnitNav, _ep2mrp, _mrp2ep

    sim = SimulationBaseClass.SimBaseClass()
    proc = sim.CreateNewProcess("p")
    proc.addTask(sim.CreateNewTask("t", macros.sec2nano(0.005)), 100)
    # a vehicle turning at a constant rate, written as Basilisk's own state message
    w = np.array([0.001, -0.002, 0.0015])
    state = messaging.SCStatesMsg()
    table = ssis.Table.read(root / "examples/basilisk/table.toml")
    unit = UnitNav(table, seed=3)
    unit.scStateInMsg.subscribeTo(state)
    if basilisk_star_tracker:
        st = starTracker.StarTracker()
        st.scStateInMsg.subscribeTo(state)
        st.dcm_CB = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
        sig = table.get("observer.st_sigma_arcsec") * math.pi / 180 / 3600
        st.PMatrix = [[sig, 0.0, 0.0], [0.0, sig, 0.0], [0.0, 0.0, sig]]
        st.setAMatrix([[0.0] * 3] * 3)
        st.setWalkBounds([1.0e3] * 3)
        proc.addTask(sim.CreateNewTask("st", macros.sec2nano(table.get("observer.st_period_s"))), 50)
        sim.AddModelToTask("st", st)
        unit.stInMsg.subscribeTo(st.sensorOutMsg)
    if basilisk_imu:
        imu = imuSensor.ImuSensor()
        imu.scStateInMsg.subscribeTo(state)
        # white rate noise of the table's ARW (a noise-free IMU at a constant rate repeats
        # its increment, and the unit refuses a repeated output as stuck)
        w_sigma = table.get("observer.arw_deg_sqrt_h") * math.pi / 180 / 60 / math.sqrt(0.005)
        imu.PMatrixGyro = [[w_sigma, 0.0, 0.0], [0.0, w_sigma, 0.0], [0.0, 0.0, w_sigma]]
        imu.setAMatrixGyro([[0.0] * 3] * 3)
        imu.setWalkBoundsGyro([1.0e3] * 3)
        sim.AddModelToTask("t", imu, 10)
        unit.imuInMsg.subscribeTo(imu.sensorOutMsg)
    sim.AddModelToTask("t", unit, 5)
    rec = unit.attOutMsg.recorder()
    sim.AddModelToTask("t", rec)
    q0 = np.array([0.9, 0.1, -0.3, 0.2])
    q0 /= np.linalg.norm(q0)

    def truth(t):
        from ssis import _ssis

        return _ssis.quat_mul(q0, _ssis.quat_from_rotation_vector(w * t))

    p = messaging.SCStatesMsgPayload()
    p.sigma_BN, p.omega_BN_B = _ep2mrp(truth(0.0)), list(w)
    state.write(p, 0)
    sim.InitializeSimulation()
    for k in range(1, 1201):
        p.sigma_BN = _ep2mrp(truth(k * 0.005))
        state.write(p, macros.sec2nano(k * 0.005))
        sim.ConfigureStopTime(macros.sec2nano(k * 0.005))
        sim.ExecuteSimulation()
    assert unit.last.st_status & ST_ALIGNED and 0 < unit.steps_before_aligned < 1200
    # the last message is the unit's last output: its attitude and rate
    np.testing.assert_allclose(rec.sigma_BN[-1], _ep2mrp(np.asarray(unit.last.q)), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(rec.omega_BN_B[-1], unit.last.rate_rad_s)
    # and it is the vehicle's attitude to the unit's accuracy (its own 3σ, 6 s in)
    err = 2 * np.abs(_mrp2ep(rec.sigma_BN[-1]) @ truth(6.0))
    err_arcsec = 2 * math.acos(min(1.0, err / 2)) * 180 / math.pi * 3600
    assert err_arcsec < 3 * np.linalg.norm(unit.last.att_sigma_arcsec)
    return unit


def test_unit_nav_publishes_the_units_attitude(root):
    unit = _fly_unit_nav(root, basilisk_star_tracker=False)
    assert unit.backend.counters()["StFramesAccepted"] > 50


def test_unit_nav_on_basilisks_star_tracker(root):
    unit = _fly_unit_nav(root, basilisk_star_tracker=True)
    assert unit.backend.counters()["StFramesAccepted"] > 50


def test_unit_nav_on_basilisks_imu(root):
    unit = _fly_unit_nav(root, basilisk_star_tracker=False, basilisk_imu=True)
    assert unit.backend.counters()["StFramesAccepted"] > 50


@pytest.mark.parametrize("seed", [3, 11])
def test_sensors_give_the_simulators_frames(tmp_path, seed):
    """The sensors ssis.basilisk flies (ssis._ssis.Sensors) and the simulator's harness
    (ssis-sim's Simulation), same seed and truth: the same FOG and star-tracker bytes,
    step for step."""
    from ssis import _ssis

    sc = tmp_path / "sc.toml"
    sc.write_text(f"seed = {seed}\n" + (Path(__file__).parent / "sensors-both-paths.toml").read_text())
    steps = _ssis.scenario_steps(sc, 2000)
    assert len(steps) == 2000
    sensors = _ssis.Sensors(
        ssis.Table.default(), seed=seed, arw_deg_sqrt_h=0.005, rrw_deg_h_sqrt_h=0.01, turn_on_bias_3sigma_deg_h=0.15,
        st_sigma_3sigma_arcsec=20, st_period_s=0.1, st_latency_s=0.05, st_outages=[(4.0, 5.0)],
    )
    stars = 0
    for k, h in enumerate(steps):
        mine = sensors.step(h["dtheta_rad"], h["q"], h["rate_rad_s"])
        assert mine["fog_frames"] == h["fog_frames"], k
        assert mine["star_bytes"] == h["star_bytes"], k
        stars += len(mine["stars"])
        # what UnitNav hands the unit is what the frames carry: whole counts of 2^-36 rad
        counts = np.asarray(mine["fog_dtheta_rad"]) * 2.0**36
        assert np.array_equal(counts, np.round(counts)), k
    # 10 Hz for 10 s less the 1-s outage, the last 50 ms still in flight
    assert stars == 89, stars
    # a different seed gives different frames
    other = _ssis.Sensors(ssis.Table.default(), seed=seed + 1, arw_deg_sqrt_h=0.005)
    assert other.step(steps[0]["dtheta_rad"], steps[0]["q"], steps[0]["rate_rad_s"])["fog_frames"] != steps[0]["fog_frames"]


def test_quaternion_maths_is_the_flight_codes():
    from ssis import _ssis

    v = np.array([0.3, -0.2, 0.1])
    q = _ssis.quat_from_rotation_vector(v)
    np.testing.assert_allclose(_ssis.rotation_vector(q), v, rtol=0, atol=1e-15)
    np.testing.assert_allclose(_ssis.quat_mul(q, _ssis.quat_conj(q)), [1, 0, 0, 0], rtol=0, atol=1e-15)
    # the shorter way round: −q is the same rotation
    np.testing.assert_allclose(_ssis.rotation_vector(-q), v, rtol=0, atol=1e-15)
    a, b = _ssis.quat_from_rotation_vector(np.array([0.0, 0.0, 0.5])), _ssis.quat_from_rotation_vector(np.array([0.0, 0.0, 0.25]))
    np.testing.assert_allclose(_ssis.rotation_vector(_ssis.quat_mul(a, b)), [0, 0, 0.75], rtol=0, atol=1e-15)
    with pytest.raises(ssis.SsisError, match="q: 3 values, expected 4"):
        _ssis.rotation_vector(np.zeros(3))


def _constant_turn_sim(root, unit_kwargs, task_s=0.005, backend=None, seconds=6.0):
    """A UnitNav on a vehicle turning at a constant rate (Basilisk's state message written
    by the test), on a task of `task_s`; returns (sim, unit, recorder, run(t_s))."""
    pytest.importorskip("Basilisk")
    from Basilisk.architecture import messaging
    from Basilisk.utilities import SimulationBaseClass, macros

    from ssis import _ssis
    from ssis.basilisk import UnitNav, _ep2mrp

    sim = SimulationBaseClass.SimBaseClass()
    proc = sim.CreateNewProcess("p")
    proc.addTask(sim.CreateNewTask("t", macros.sec2nano(task_s)), 100)
    w = np.array([0.001, -0.002, 0.0015])
    q0 = np.array([0.9, 0.1, -0.3, 0.2])
    q0 /= np.linalg.norm(q0)
    state = messaging.SCStatesMsg()
    table = ssis.Table.read(root / "examples/basilisk/table.toml")
    if backend is not None:
        unit_kwargs = dict(unit_kwargs, backend=backend(table))
    unit = UnitNav(table, seed=5, **unit_kwargs)
    unit.scStateInMsg.subscribeTo(state)
    sim.AddModelToTask("t", unit, 5)
    rec = unit.attOutMsg.recorder()
    sim.AddModelToTask("t", rec)
    p = messaging.SCStatesMsgPayload()
    p.omega_BN_B = list(w)

    def truth(t):
        return _ssis.quat_mul(q0, _ssis.quat_from_rotation_vector(w * t))

    p.sigma_BN = _ep2mrp(truth(0.0))
    state.write(p, 0)
    sim.InitializeSimulation()

    def run(t_end):
        k = 1
        while k * task_s <= t_end + 1e-12:
            p.sigma_BN = _ep2mrp(truth(k * task_s))
            state.write(p, macros.sec2nano(k * task_s))
            sim.ConfigureStopTime(macros.sec2nano(k * task_s))
            sim.ExecuteSimulation()
            k += 1

    return unit, rec, truth, run


def test_unit_nav_refuses_any_task_period_but_the_units_step(root):
    unit, _, _, run = _constant_turn_sim(root, {}, task_s=0.010)
    with pytest.raises(RuntimeError):
        run(0.05)
    assert isinstance(unit.error, ValueError)
    assert "UnitNav runs every 10 ms: the unit steps every 5 ms" in str(unit.error)
    assert unit.backend.core.steps == 0


class _LosesAlignment:
    """The in-process core, with ALIGNED and CONVERGED cleared in its output over
    [t0, t1) (a unit that loses its status after its first alignment)."""

    def __init__(self, table, t0=3.0, t1=3.5):
        from ssis.basilisk import InProcess

        self.inner = InProcess(table)
        self.t0, self.t1 = t0, t1
        self.outputs = []

    def step(self, d, star, temps=None, valid=True):
        import dataclasses

        from ssis.basilisk import CONVERGED, ST_ALIGNED

        out = self.inner.step(d, star, temps, valid)
        if self.t0 <= out.time_s < self.t1:
            out = dataclasses.replace(out, st_status=out.st_status & ~ST_ALIGNED, flags=out.flags & ~CONVERGED)
        self.outputs.append(out)
        return out

    def counters(self):
        return self.inner.counters()


def test_unit_nav_flies_the_unit_after_its_first_alignment_and_reports_each_loss(root):
    from ssis.basilisk import ST_ALIGNED, UnitStatusWarning, _ep2mrp

    unit, rec, truth, run = _constant_turn_sim(root, {}, backend=_LosesAlignment)
    with pytest.warns(UnitStatusWarning, match="lost ALIGNED at t = 3.000 s") as caught:
        run(6.0)
    outs = unit.backend.outputs
    first = next(k for k, o in enumerate(outs) if o.st_status & ST_ALIGNED)
    # truth before the first alignment, and only then: it is counted and timed
    assert unit.steps_before_aligned == first > 0
    assert unit.first_aligned_s == pytest.approx((first + 1) * 0.005)
    sig = np.asarray(rec.sigma_BN)
    for k in range(first):
        np.testing.assert_allclose(sig[k + 1], _ep2mrp(truth((k + 1) * 0.005)), rtol=0, atol=1e-12)
    # after it, the unit's output at every step, the unaligned ones included
    lost = [k for k, o in enumerate(outs) if k > first and not o.st_status & ST_ALIGNED]
    assert len(lost) == 100, len(lost)
    for k in range(first, len(outs)):
        np.testing.assert_allclose(sig[k + 1], _ep2mrp(outs[k].q), rtol=0, atol=1e-15)
    # the unit's output is not the truth (or the test above proves nothing)
    assert np.max(np.abs(sig[lost[0] + 1] - _ep2mrp(truth((lost[0] + 1) * 0.005)))) > 1e-9
    # each loss reported and counted, and each regain
    assert [round(t, 3) for t, _ in unit.losses] == [3.0] * sum(1 for _, k in unit.losses)
    assert {k for _, k in unit.losses} >= {"aligned"}
    assert unit.status_losses == len(unit.losses) == sum(issubclass(w.category, UnitStatusWarning) for w in caught)
    assert unit.realignments == 1


def test_unit_nav_strict_raises_on_a_status_loss(root):
    from ssis.basilisk import UnitStatusLost

    unit, _, _, run = _constant_turn_sim(root, {"strict": True}, backend=_LosesAlignment)
    with pytest.raises(RuntimeError):
        run(6.0)
    assert isinstance(unit.error, UnitStatusLost)
    assert "lost ALIGNED at t = 3.000 s" in str(unit.error)
