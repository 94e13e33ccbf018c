"""What a notebook or a campaign of runs needs: pickle and copy (a forked core continues bit
for bit), batch stepping from arrays, tables from text, pandas frames, named status bits,
short reprs."""

import copy
import math
import pickle

import numpy as np
import pytest

import ssis
from ssis import lab

DT = 0.005
W_RAD_S = np.radians(0.1)  # a 0.1 °/s turn about the instrument's z axis


def _flight(n, seed=1):
    """``n`` steps of a z turn seen by the nominal FOGs (white noise), a star solution every
    50 steps (the tracker at 4 Hz) tagged at the end of its step."""
    rng = np.random.default_rng(seed)
    axes = np.array(ssis.Table.default().axes())
    dtheta = (axes @ np.array([0.0, 0.0, W_RAD_S * DT]))[None, :] + rng.normal(0, 2e-8, size=(n, 4))
    t = np.arange(1, n + 1) * DT
    star_t = np.full(n, math.nan)
    star_q = np.zeros((n, 4))
    star_q[:, 0] = 1.0
    k = np.arange(49, n, 50)
    star_t[k] = t[k]
    half = W_RAD_S * t[k] / 2
    star_q[k] = np.stack([np.cos(half), 0 * half, 0 * half, np.sin(half)], axis=1)
    return dtheta, star_t, star_q


def _steps(core, dtheta, star_t, star_q):
    out = []
    for k in range(len(dtheta)):
        star = None if math.isnan(star_t[k]) else (star_t[k], star_q[k])
        out.append(core.step(dtheta[k], star))
    return out


def test_run_is_step_by_step_bit_for_bit():
    dtheta, st, sq = _flight(3000)
    a, b = ssis.FlightCore(), ssis.FlightCore()
    steps = _steps(a, dtheta, st, sq)
    r = b.run(dtheta, st, sq)
    assert len(r) == 3000 and r.q.shape == (3000, 4) and r.fog_health.shape == (3000, 4)
    np.testing.assert_array_equal(r.q, [s.q for s in steps])
    np.testing.assert_array_equal(r.drift_rad_s, [s.drift_rad_s for s in steps])
    np.testing.assert_array_equal(r.att_sigma_arcsec, [s.att_sigma_arcsec for s in steps])
    np.testing.assert_array_equal(r.flags, [s.flags for s in steps])
    np.testing.assert_array_equal(r.st_status, [s.st_status for s in steps])
    np.testing.assert_array_equal(r.fog_health, [s.fog_health for s in steps])
    assert [e["event"] for e in r.events] == [e["event"] for s in steps for e in s.events]
    assert r.aligned[-1] and steps[-1].aligned
    assert a.counters() == b.counters() and a.steps == b.steps == 3000
    assert all(isinstance(h, int) for h in steps[-1].fog_health)


def test_a_pickled_or_copied_core_continues_bit_for_bit():
    dtheta, st, sq = _flight(4000, seed=2)
    core = ssis.FlightCore()
    core.run(dtheta[:2000], st[:2000], sq[:2000])
    forks = [pickle.loads(pickle.dumps(core)), copy.copy(core), copy.deepcopy(core)]
    want = core.run(dtheta[2000:], st[2000:], sq[2000:])
    for f in forks:
        assert f.steps == 2000
        got = f.run(dtheta[2000:], st[2000:], sq[2000:])
        for name, a in want.arrays().items():
            np.testing.assert_array_equal(getattr(got, name), a, err_msg=name)
        assert got.events == want.events
        assert f.counters() == core.counters()
    # a fork is independent of its parent
    assert forks[1]._native is not core._native
    with pytest.raises(ssis.SsisError, match="pickled"):
        ssis._ssis.FlightCore().__setstate__(b"SSISFC01" + b"\0" * 30)


def test_table_model_session_pickle_and_copy(tmp_path):
    t = ssis.Table.default()
    t.set("fog[2].bias_rad_s", 1.2345678901234567e-6)
    t.set("observer.st_sigma_arcsec", 3.3)
    for u in (pickle.loads(pickle.dumps(t)), copy.copy(t), copy.deepcopy(t)):
        assert u == t and u.crc == t.crc and u.to_toml() == t.to_toml()
    assert ssis.Table.from_toml(t.to_toml()) == t
    c = ssis.FlightCore(t)
    assert pickle.loads(pickle.dumps(c)).counters() == c.counters()

    p = tmp_path / "th.csv"
    lab.simulate("thermal", p, seed=5)
    s = lab.Session.read(p)
    s2 = pickle.loads(pickle.dumps(s))
    assert s2.names == s.names and len(s2) == len(s) and s2.to_csv() == s.to_csv()
    for n in s.names:
        np.testing.assert_array_equal(s2[n], s[n])
    m = lab.fit(lab.Model.init(), s)
    for m2 in (pickle.loads(pickle.dumps(m)), copy.copy(m), copy.deepcopy(m)):
        assert m2 == m and m2.to_toml() == m.to_toml() and m2.fitted
    assert lab.compare(m, s2) == lab.compare(m, s)
    assert "fitted=True" in repr(m) and len(repr(s)) < 200


def test_pandas_frames_have_one_column_per_scalar(short_log, root):
    pd = pytest.importorskip("pandas")
    r = ssis.replay(short_log, ssis.Table.read(root / "examples/basilisk/table.toml"), decimate=10)
    df = r.to_pandas()
    assert isinstance(df, pd.DataFrame) and len(df) == len(r.t_s)
    for c in ["t_s", "q0", "q1", "q2", "q3", "rate_rad_s_x", "drift_rad_s_z", "att_err_arcsec_y", "flags"]:
        assert c in df.columns, c
    np.testing.assert_array_equal(df["q3"], r.q[:, 3])
    assert len(repr(r)) < 300 and "<table>" in r._repr_html_()
    run = ssis.FlightCore().run(*_flight(100))
    assert {"q0", "fog_health_fog3", "st_status"} <= set(run.to_pandas().columns)
    a = ssis.cal.allan(np.random.default_rng(1).normal(0, 1e-6, 20000), 0.1)
    assert list(a.to_pandas().columns) == ["tau_s", "adev_deg_h", "ci95_low_deg_h", "ci95_high_deg_h"]
    assert len(repr(a)) < 300


def test_version_and_status_names():
    assert ssis.__version__ and ssis.__version__ == ssis._ssis.__version__
    core = ssis.FlightCore()
    s = core.step(np.zeros(4))
    assert not s.aligned and not s.converged
    assert isinstance(s.fog_health, list) and all(isinstance(h, int) for h in s.fog_health)
    assert len(repr(s)) < 300 and len(repr(core)) < 200
