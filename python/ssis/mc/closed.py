"""Closed-loop runs (``loop = "closed"``): Basilisk flies the LEO spacecraft of
:func:`ssis.basilisk.fly_leo` on the unit (:class:`ssis.basilisk.UnitNav`), one run per
draw of the campaign (docs/MONTE-CARLO.md, "Closed loop").

Run i draws what the open loop draws (the native ``mc_draw``: the same parameters, the
dispersed true errors, the noise seed, the faults); the unit flies the base table, its
sensors the dispersed truth (``UnitNav(truth=…)``). The indices:

- AKE, RKE, KDE on the knowledge error (the unit's navigation message against the
  vehicle's true attitude, per axis), through the native ``mc_indices``, so they are
  computed as the open loop computes them;
- APE, RPE, PDE: the same statistics on the performance error the unit adds: the true
  attitude against the controller's reference, less the same flight's on truth
  navigation (``fly_leo(None, …)``: the controller's own slew transients, the same in
  every run since the flights are deterministic, flown once per worker process), named
  as ECSS names them.

:func:`via_basilisk_controller` runs the same runs through Basilisk's own
``Basilisk.utilities.MonteCarlo.Controller``, for the comparison of BENCHMARKS.md.
"""

from __future__ import annotations

import copy
import json
import os
import re
import tempfile
import time
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np

from .. import Table, _ssis

__all__ = ["run", "via_basilisk_controller"]

PERFORMANCE = {"AKE": "APE", "RKE": "RPE", "KDE": "PDE"}
"""The name of a knowledge index's statistic on the performance error."""


_SCENARIO_FIELDS = ("star_tracker.latency_ms", "star_tracker.misalignment_arcsec")
"""The scenario numbers a closed-loop campaign may disperse (what UnitNav models)."""


def _toml(text: str) -> Dict[str, Any]:
    try:
        import tomllib
    except ImportError:  # Python < 3.11
        import tomli as tomllib  # type: ignore[no-redef,import-not-found,unused-ignore]
    return tomllib.loads(text)


def _rotvec_quat(v: np.ndarray) -> np.ndarray:
    a = float(np.linalg.norm(v))
    if a == 0.0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return np.concatenate([[np.cos(a / 2)], np.sin(a / 2) * v / a])


def setup(info: Dict[str, Any], draw: Dict[str, Any], table: Table) -> Dict[str, Any]:
    """UnitNav's arguments for a draw: the unit flies ``table``; its sensors' truth is
    ``table`` plus each table quantity's δ, with the tracker mounted off the table's mount
    by the dispersed scenario's ``star_tracker.misalignment_arcsec`` (as the simulator
    mounts it); the FOG noise, turn-on bias and the tracker's noise, period and latency
    are the dispersed scenario's, the noise seed the run's; a FOG lost, a tracker outage.
    A reset is not flown in closed loop (UnitNav has none): a run that draws one fails."""
    truth = copy.copy(table)
    params = draw["params"]
    for q in info["quantities"]:
        target = q["target"]
        if "table" in target:
            for name in target["table"]:
                truth.set(name, truth.get(name) + float(params[q["name"]]))
        elif str(target.get("scenario")).split("[")[0] not in _SCENARIO_FIELDS:
            raise ValueError(f"{q['name']}: a closed-loop campaign disperses table fields and "
                             f"{', '.join(_SCENARIO_FIELDS)} (what UnitNav models)")
    sc = _toml(draw["scenario_toml"])
    st, fog = sc.get("star_tracker", {}), sc.get("fog", {})
    mis = np.asarray(st.get("misalignment_arcsec", [0.0, 0.0, 0.0]), dtype=float) / (180 / np.pi * 3600)
    if mis.any():
        mount = np.array([truth.get(f"st_mount_q[{k}]") for k in range(4)])
        q = _ssis.quat_mul(mount, _rotvec_quat(mis))
        for k in range(4):
            truth.set(f"st_mount_q[{k}]", float(q[k]))
    outage: Optional[Tuple[float, float]] = None
    fog_failure = None
    for f in draw["faults"]:
        if f["kind"] == "star-outage":
            if outage is not None:
                raise ValueError(f"run {draw['run']}: UnitNav flies one tracker outage per run")
            outage = (float(f["t_s"]), float(f["t_s"]) + float(f["duration_s"]))
        elif f["kind"] == "fog-lost":
            if fog_failure is not None:
                raise ValueError(f"run {draw['run']}: UnitNav flies one FOG failure per run")
            fog_failure = (float(f["t_s"]), int(f["fog"]), "dead")
        else:
            raise ValueError(f"run {draw['run']}: a `{f['kind']}` fault is not flown in closed loop "
                             "(fog-lost, star-outage)")
    kw: Dict[str, Any] = dict(table=table, truth=truth, seed=int(sc["seed"]), st_outage=outage,
                              fog_failure=fog_failure, st_latency_s=float(st.get("latency_ms", 50.0)) * 1e-3)
    if "arw_deg_sqrt_h" in fog:
        kw["arw_deg_sqrt_h"] = float(fog["arw_deg_sqrt_h"])
    if "rrw_deg_h_sqrt_h" in fog:
        kw["rrw_deg_h_sqrt_h"] = float(fog["rrw_deg_h_sqrt_h"])
    if "random_bias_3sigma_deg_h" in fog:
        kw["turn_on_bias_deg_h"] = float(fog["random_bias_3sigma_deg_h"]) / 3
    if "sigma_3sigma_arcsec" in st:
        kw["st_sigma_arcsec"] = float(st["sigma_3sigma_arcsec"]) / 3
    if st.get("rate_hz"):
        kw["st_period_s"] = 1.0 / float(st["rate_hz"])
    return kw


def _table(info: Dict[str, Any]) -> Table:
    """The unit's table: the scenario's ``[table] file`` (relative to the scenario), else the default."""
    t = info.get("scenario", {}).get("table", {})
    if isinstance(t, dict) and t.get("file"):
        return Table.read(os.path.join(os.path.dirname(info["scenario_path"]), t["file"]))
    return Table.default()


_TRUTH: Dict[float, np.ndarray] = {}
"""The truth flight's pointing error per duration, flown once per process."""


def truth_pointing_arcsec(duration_s: float) -> np.ndarray:
    """The pointing error of the flight on truth navigation (``fly_leo(None, …)``), arcsec."""
    if duration_s not in _TRUTH:
        from ..basilisk import fly_leo

        _TRUTH[duration_s] = np.asarray(fly_leo(None, duration_s)["pointing_arcsec"], dtype=float)
    return _TRUTH[duration_s]


def run(text: str, origin: str, i: int, series_every: int = 0) -> Dict[str, Any]:
    """Closed-loop run ``i``: ``run``, ``params``, ``indices`` (knowledge and performance),
    ``steps``, optional ``series`` (every ``series_every``-th 5-ms sample of both errors)."""
    import warnings

    from ..basilisk import UnitNav, fly_leo

    info = json.loads(_ssis.mc_validate(text, origin))
    d = dict(_ssis.mc_draw(text, origin, i))
    unit = UnitNav(**setup(info, d, _table(info)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # status losses are part of the statistics, not news
        f = fly_leo(unit, float(info["scenario"]["duration_s"]))
    spec = json.dumps(info["indices"])
    t = np.ascontiguousarray(f["t_s"], dtype=float)
    know = dict(_ssis.mc_indices(t, np.ascontiguousarray(f["nav_err_arcsec"], dtype=float), spec))
    duration_s = float(info["scenario"]["duration_s"])
    added = np.asarray(f["pointing_arcsec"], dtype=float) - truth_pointing_arcsec(duration_s)
    perf = dict(_ssis.mc_indices(t, np.ascontiguousarray(added), spec))
    indices = dict(know)
    for k, v in perf.items():
        stem, rest = k.split("_", 1)
        indices[f"{PERFORMANCE.get(stem, stem + 'p')}_{rest}"] = v
    out: Dict[str, Any] = {"run": i, "params": dict(d["params"]), "indices": indices, "steps": len(t),
                           "status_losses": unit.status_losses}
    if series_every > 0:
        s = slice(None, None, series_every)
        out["series"] = {"t_s": t[s], "err_arcsec": np.asarray(f["nav_err_arcsec"])[s],
                         "pointing_arcsec": np.asarray(f["pointing_arcsec"])[s], "added_arcsec": added[s]}
    return out


# ---------------------------------------------------------------------------------------
# The same runs through Basilisk's MonteCarlo.Controller.

_CAMPAIGN: Dict[str, str] = {}


def _bsk_create() -> Any:
    from Basilisk.utilities import SimulationBaseClass  # type: ignore

    return SimulationBaseClass.SimBaseClass()


def _bsk_execute(sim: Any, filename: str) -> None:
    """Controller's execution function: run i is named by the file it gives (``run<i>``)."""
    m = re.search(r"run(\d+)$", filename)
    if m is None:
        raise ValueError(f"{filename}: no run number")
    c = json.loads(os.environ["SSIS_MC_CAMPAIGN"])
    r = run(c["text"], c["origin"], int(m.group(1)))
    with open(filename + ".ssis.json", "w") as fh:
        json.dump({"run": r["run"], "indices": r["indices"]}, fh)


def via_basilisk_controller(text: str, origin: str, runs: Sequence[int], threads: int = 2,
                            archive: Optional[str] = None) -> Tuple[List[Dict[str, Any]], float]:
    """Runs ``runs`` (0 … n−1) through ``Basilisk.utilities.MonteCarlo.Controller`` with
    ``threads`` processes; returns each run's indices (from the files its execution
    function writes) and the wall time."""
    from Basilisk.utilities.MonteCarlo.Controller import Controller  # type: ignore

    n = max(runs) + 1
    if list(runs) != list(range(n)):
        raise ValueError("the Controller runs cases 0 … n−1")
    archive = archive or tempfile.mkdtemp(prefix="ssis-mc-bsk-")
    os.environ["SSIS_MC_CAMPAIGN"] = json.dumps({"text": text, "origin": origin})
    mc = Controller()
    mc.setSimulationFunction(_bsk_create)
    mc.setExecutionFunction(_bsk_execute)
    mc.setExecutionCount(n)
    mc.setThreadCount(threads)
    mc.setShouldDisperseSeeds(False)
    mc.setShouldArchiveParameters(True)
    mc.setArchiveDir(archive)
    mc.setVerbose(False)
    t0 = time.perf_counter()
    failed = mc.executeSimulations()
    wall = time.perf_counter() - t0
    if failed:
        raise RuntimeError(f"Basilisk's Controller: runs {failed} failed")
    out = []
    for i in range(n):
        with open(os.path.join(archive, f"run{i}.ssis.json")) as fh:
            out.append(json.load(fh))
    return out, wall
