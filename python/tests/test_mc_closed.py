"""Closed-loop Monte Carlo (loop = "closed"): Basilisk with UnitNav per run; the same runs
through Basilisk's own MonteCarlo.Controller give the same indices."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Callable

import numpy as np
import pytest

pytest.importorskip("Basilisk")
pytest.importorskip("dask.distributed")
pytest.importorskip("pyarrow")

import ssis.mc as mc  # noqa: E402
from ssis.mc import closed  # noqa: E402

BIN = Path(sys.executable).parent


def test_closed_loop_runs_match_basilisks_controller(tmp_path: Path, campaign: Callable[..., Path]) -> None:
    """Three 40-s closed-loop runs on a local cluster of two workers and through
    ``MonteCarlo.Controller`` (two processes): the same indices, bit for bit; the
    performance indices (APE, RPE, PDE) beside the knowledge ones."""
    c = campaign(3, 40.0, name="closed", loop="closed")
    o = mc.run(c, tmp_path / "out", workers=2, progress=False)
    assert o.errors == [], o.errors
    df = mc.load(tmp_path / "out")
    keys = [k for k in df.columns if k.startswith(mc.INDEX)]
    for stem in ("AKE", "RKE", "KDE", "APE", "RPE", "PDE"):
        assert any(k[len(mc.INDEX):].startswith(stem) for k in keys), (stem, keys)
    camp = mc.Campaign.read(c)
    bsk, wall = closed.via_basilisk_controller(camp.text, camp.origin, range(3), threads=2,
                                               archive=str(tmp_path / "bsk"))
    assert wall > 0
    for r in bsk:
        row = df[df["run"] == r["run"]].iloc[0]
        for k, v in r["indices"].items():
            assert np.float64(v).view(np.int64) == np.float64(row[mc.INDEX + k]).view(np.int64), (r["run"], k)


def test_performance_error_is_what_the_unit_adds(campaign: Callable[..., Path]) -> None:
    """APE/RPE/PDE take the pointing error less the truth-navigation flight's. UnitNav
    publishes truth until the unit's first alignment, so until then the two flights are the
    same and the added error is exactly zero; after it the unit's navigation error moves
    the vehicle and the added error is not zero. Were the two series misaligned in time, or
    the truth flight not the same vehicle, the first part would not be zero."""
    c = campaign(1, 40.0, name="added", loop="closed")
    camp = mc.Campaign.read(c)
    r = closed.run(camp.text, camp.origin, 0, series_every=1)
    added = np.asarray(r["series"]["added_arcsec"])
    point = np.asarray(r["series"]["pointing_arcsec"])
    t = np.asarray(r["series"]["t_s"])
    assert added.shape == point.shape == (len(t), 3)
    before = t < 1.0  # the tracker's first solution is after 1 s at its 10-Hz rate and latency
    assert before.sum() > 100 and np.all(added[before] == 0.0)
    assert np.abs(added[~before]).max() > 0.0
    # the truth flight's own error (slew transients) is not in it
    truth = closed.truth_pointing_arcsec(40.0)
    assert np.array_equal(point - truth, added)


def test_json_output_is_one_document(tmp_path: Path, campaign: Callable[..., Path]) -> None:
    """``ssis-mc run … --json`` and ``replay … --json`` on a closed-loop campaign: Basilisk
    logs (BSK_INFORMATION) while it flies, yet standard output is the one JSON document and
    the log lines are on standard error."""
    c = campaign(1, 40.0, name="json", loop="closed")
    q = subprocess.run([str(BIN / "ssis-mc"), "run", str(c), "--out", str(tmp_path / "out"), "--scheduler", "serial",
                        "--no-progress", "--json"], capture_output=True, text=True, timeout=300)
    assert q.returncode == 0, q.stderr
    assert json.loads(q.stdout)["completed"] == 1
    assert "BSK_INFORMATION" in q.stderr, "Basilisk logged nothing: the test would not show a mixed output"
    r = subprocess.run([str(BIN / "ssis-mc"), "replay", str(c), "--run", "0", "--json"], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert set(json.loads(r.stdout)["indices"]) and "BSK_INFORMATION" in r.stderr
