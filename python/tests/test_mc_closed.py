"""Closed-loop Monte Carlo (loop = "closed"): Basilisk with UnitNav per run; the same runs
through Basilisk's own MonteCarlo.Controller give the same indices."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("Basilisk")
pytest.importorskip("dask.distributed")
pytest.importorskip("pyarrow")

import ssis.mc as mc  # noqa: E402
from ssis.mc import closed  # noqa: E402

from test_mc import campaign  # noqa: E402


def test_closed_loop_runs_match_basilisks_controller(tmp_path: Path) -> None:
    """Three 40-s closed-loop runs on a local cluster of two workers and through
    ``MonteCarlo.Controller`` (two processes): the same indices, bit for bit; the
    performance indices (APE, RPE, PDE) beside the knowledge ones."""
    c = campaign(tmp_path, 3, 40.0, name="closed")
    c.write_text(c.read_text().replace('duration_s = 40.0\n', 'duration_s = 40.0\nloop = "closed"\n', 1))
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
