"""ssis.basilisk and the QEMU backend: the module publishes what the unit output, and the
firmware in QEMU outputs what the in-process core does on the same steps."""

import math
import os
import shutil

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
    assert isolated["a"] == 3 and isolated["details"] == "FOG3"


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
        from ssis.basilisk import _qexp, _qmul

        return _qmul(q0, _qexp(w * t))

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
