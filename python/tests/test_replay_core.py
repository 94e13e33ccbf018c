"""ssis.replay against ``ssis-sim replay --json``, and ssis.FlightCore step by step against
the replay on the same log."""

import math

import numpy as np

import ssis


def test_replay_summary_is_the_command_lines(cli, short_log, root):
    table = root / "examples/basilisk/table.toml"
    calls = []
    r = ssis.replay(short_log, ssis.Table.read(table), progress=lambda d, t: calls.append((d, t)))
    v = cli.json("ssis-sim", "replay", short_log, "--table", table)
    assert r.summary == v["replay"]
    assert r.conventions == v["conventions"]
    n = v["replay"]["steps"]
    assert len(r.t_s) == n and r.q.shape == (n, 4) and r.att_err_arcsec.shape == (n, 3)
    assert calls[-1] == (n, n) and len(calls) > 10
    # the arrays give the summary's figure: attitude error 3σ = |mean| + 3 std after settling
    rows = (r.t_s >= 60.0) & ~np.isnan(r.att_err_arcsec[:, 0])
    e = r.att_err_arcsec[rows]
    three_sigma = np.abs(e.mean(axis=0)) + 3 * e.std(axis=0)
    want = v["replay"]["accuracy"]["attitude_error_3sigma_arcsec"]
    np.testing.assert_allclose(three_sigma, want, rtol=1e-9)


def test_replay_decimated_and_summary_only_keep_the_summary(short_log, root):
    table = ssis.Table.read(root / "examples/basilisk/table.toml")
    full = ssis.replay(short_log, table)
    every = ssis.replay(short_log, table, decimate=7)
    none = ssis.replay(short_log, table, summary_only=True)
    assert every.summary == full.summary and none.summary == full.summary
    assert every.conventions == full.conventions and none.report == full.report
    np.testing.assert_array_equal(every.t_s, full.t_s[::7])
    np.testing.assert_array_equal(every.q, full.q[::7])
    np.testing.assert_array_equal(every.att_err_arcsec, full.att_err_arcsec[::7])
    assert len(none.t_s) == 0 and none.q.shape == (0, 4)


def _read_log(path):
    """The log's FOG increments and star solutions per row (the reader's unit time)."""
    names = None
    rows = []
    with open(path) as f:
        for line in f:
            if line.startswith("#"):
                continue
            if names is None:
                names = line.strip().split(",")
                continue
            rows.append([float(x) if x else math.nan for x in line.strip().split(",")])
    a = np.array(rows)
    col = {n: a[:, i] for i, n in enumerate(names)}
    return col


def test_flight_core_steps_as_the_replay(short_log, root):
    table = ssis.Table.read(root / "examples/basilisk/table.toml")
    r = ssis.replay(short_log, table)
    c = _read_log(short_log)
    t0 = c["t_s"][0] - 0.005  # unit time 0 is one interval before the first sample
    core = ssis.FlightCore(table)
    q = np.empty((len(c["t_s"]), 4))
    drift = np.empty((len(c["t_s"]), 3))
    accepted = 0
    events = []
    for k in range(len(c["t_s"])):
        d = [c[f"fog{i}_dtheta_rad"][k] for i in range(4)]
        star = None
        if not math.isnan(c["st_t_s"][k]):
            sq = [c[f"st_q{i}"][k] for i in range(4)]
            norm = math.sqrt(sum(v * v for v in sq))  # the log reader normalises, in this order
            star = (c["st_t_s"][k] - t0, [v / norm for v in sq])
        s = core.step(d, star, star_valid=c["st_valid"][k] == 1)
        q[k], drift[k] = s.q, s.drift_rad_s
        accepted += dict(s.counters_moved).get("StFramesAccepted", 0)
        events += s.events
        assert abs(s.time_s - r.t_s[k]) < 1e-9
    # the replay's arrays are the output frames': q in counts of 2^-31, saturated
    counts = np.clip(np.round(q * 2**31), -(2**31), 2**31 - 1)
    np.testing.assert_array_equal(counts, np.round(r.q * 2**31))
    lsb = np.min(np.abs(np.diff(np.unique(r.drift_rad_s))))
    assert np.max(np.abs(drift - r.drift_rad_s)) <= lsb
    assert accepted == core.counters()["StFramesAccepted"] > 800
    # the event log: aligned on the tracker once, at an output's time, then converged
    names = [e["event"] for e in events]
    assert names.count("aligned") == 1, names
    aligned = next(e for e in events if e["event"] == "aligned")
    assert 0.0 < aligned["time_s"] <= r.t_s[-1]
    assert any(abs(aligned["time_s"] - t) < 1e-9 for t in r.t_s), aligned
    assert [e["seq"] for e in events] == list(range(events[0]["seq"], events[0]["seq"] + len(events)))
