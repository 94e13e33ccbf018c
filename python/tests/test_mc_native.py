"""The Monte Carlo functions of the native module (python/src/mc.rs, docs/MONTE-CARLO.md):
the campaign checked with its errors named, run i the same however it is asked for, and
``mc_indices`` on a run's own series giving that run's indices bit for bit (the closed
loop computes its indices this way)."""

import json
from pathlib import Path

import numpy as np
import pytest

import ssis
from ssis import _ssis

ORIGIN = str(Path(__file__).resolve().parents[2] / "host-tests" / "scenarios" / "mc-pytest.toml")

RUNS, DURATION_S = 4, 60.0


@pytest.fixture
def text(campaign_text):
    """The Monte Carlo tests' campaign (conftest.py): four 60-s runs."""
    return campaign_text(RUNS, DURATION_S, name="pytest")


def same(a, b):
    """Equal dicts of floats, NaN equal to NaN (a fault that did not occur has NaN times)."""
    return list(a) == list(b) and np.array_equal(list(a.values()), list(b.values()), equal_nan=True)


def test_validate_normalises_and_names_what_is_wrong(text):
    c = json.loads(_ssis.mc_validate(text, ORIGIN))
    assert c["runs"] == RUNS and c["loop"] == "open"
    assert c["params"][:2] == ["table.fog[0].bias_rad_s", "table.fog[1].bias_rad_s"]
    assert c["params"][-3:] == ["fault[0].fog-lost.occurs", "fault[0].fog-lost.t_s", "fault[0].fog-lost.fog"]
    assert c["index_keys"][-1] == "KDE_6s_18s_z"
    with pytest.raises(ssis.SsisError, match="did you mean `runs`"):
        _ssis.mc_validate(text.replace(f"runs = {RUNS}", f"rnus = {RUNS}"), ORIGIN)
    with pytest.raises(ssis.SsisError, match=r"mc-pytest\.toml.*disperse\[1\]\.low"):
        _ssis.mc_validate(text.replace("low = -10.0", "low = 11.0"), ORIGIN)


def test_a_run_is_the_same_alone_and_in_a_batch_and_its_indices_are_mc_indices(text):
    c = json.loads(_ssis.mc_validate(text, ORIGIN))
    alone = _ssis.mc_run(text, ORIGIN, 2, series_every=1)
    batch = _ssis.mc_runs(text, ORIGIN, [3, 2, 0])
    assert batch[1]["run"] == 2
    assert same(batch[1]["indices"], alone["indices"]) and same(batch[1]["params"], alone["params"])
    assert list(alone["indices"]) == c["index_keys"] and list(alone["params"]) == c["params"]
    assert batch[0]["digest"] != batch[1]["digest"]
    s = alone["series"]
    assert s["err_arcsec"].shape == (alone["evaluated"], 3)
    keep = s["t_s"] >= c["indices"]["from_s"]
    again = _ssis.mc_indices(s["t_s"][keep], np.ascontiguousarray(s["err_arcsec"][keep]), json.dumps(c["indices"]))
    assert same(again, alone["indices"])
    with pytest.raises(ssis.SsisError, match="err_arcsec"):
        _ssis.mc_indices(s["t_s"], np.zeros((3, 3)), json.dumps(c["indices"]))


def test_draw_gives_the_params_and_the_scenario_a_closed_loop_flies(text):
    d = _ssis.mc_draw(text, ORIGIN, 1)
    r = _ssis.mc_run(text, ORIGIN, 1)
    assert same(d["params"], r["params"])
    assert "latency_ms" in d["scenario_toml"]
    assert len(d["faults"]) == int(d["params"]["fault[0].fog-lost.occurs"])
