#!/usr/bin/env python3
"""A LEO spacecraft flown in Basilisk on the unit's attitude, beside the same flight on truth.

The vehicle (Basilisk 2.12.1: `spacecraft`, 750 kg, inertia diag(900, 800, 600) kg m², a
500-km circular orbit at 51.6°, point-mass Earth) holds nadir (`hillPoint`) with slews as
steps of `attTrackingError`'s reference offset (15° about X at 40 s, −20° about (0, 0.6,
0.8) at 110 s, 15° about −X at 145 s, back to nadir at 180 s; repeated every 180 s), under
`mrpFeedback` (K = 36, P = 160) commanding `extForceTorque`. The flight software's
navigation message comes from:

  truth   `simpleNav` without noise (the vehicle's own motion);
  unit    ssis.basilisk.UnitNav: the unit's attitude and rate, from its FOGs and star tracker
          (--backend in-process: the flight core; qemu: the firmware in QEMU in lockstep)
          (examples/basilisk/table.toml's figures: ARW 0.05 °/√h, bias walk 0.01 °/h/√h,
          tracker 20/3″ 1σ per axis every 0.1 s, 50 ms latency);
  outage  the unit, with no star-tracker solution between --outage T0,T1;
  fog     the unit, with FOG --fog-index failed at --fog-at (--fog-mode: dead, or a bias
          step in °/h).

A fault given outside the flight (--outage or --fog-at at or after --duration) is refused;
the default fault windows (outage 30–90 s, FOG at 20 s) are moved into a shorter flight
(the same fractions of it), and the script says so.

UnitNav flies truth only until the unit's first alignment; after it the flight software
controls on the unit's output whatever its status, and every loss of ALIGNED or
CONVERGED is reported (a warning, counted in the summary line; --strict stops the flight).

The pointing error is the vehicle's true attitude against the reference (a second
`attTrackingError` fed with truth), per axis, arcsec. The flights are deterministic, so
the truth flight's pointing error is the controller's own (slew transients); what a unit
flight adds to it, sample by sample, is what the unit's errors, latency and faults do to
pointing. The script prints, after --settle, the pointing error's RMS, the part the unit
adds (RMS, 3σ = |mean| + 3 std, max) and the unit's own attitude error (its message
against truth, 3σ).

    python3 closed_loop.py --duration 100 [--scenarios truth,unit,outage,fog] [--json out.json]

(truth must come first for the comparison.)
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

import ssis
from ssis.basilisk import UnitNav, fly_leo

DT = 0.005
HERE = Path(__file__).resolve().parent
# the lines of the QEMU runner's report worth printing beside each flight
KEEP = ("host/QEMU equivalence", "step time, instructions", "unit counters", "QEMU exit")


DEFAULT_OUTAGE_S = (30.0, 90.0)
DEFAULT_FOG_AT_S = 20.0
DEFAULT_SPAN_S = 100.0


def place_faults(a: argparse.Namespace, kinds: list) -> list:
    """Puts the fault windows in the flight: refuses a given one outside --duration, moves
    a default one into a shorter flight. Returns the notes to print; ValueError for a refusal."""
    notes = []
    d = a.duration
    if a.outage is None:
        a.outage = list(DEFAULT_OUTAGE_S)
        if d < DEFAULT_SPAN_S and "outage" in kinds:
            a.outage = [DEFAULT_OUTAGE_S[0] / DEFAULT_SPAN_S * d, DEFAULT_OUTAGE_S[1] / DEFAULT_SPAN_S * d]
            notes.append(f"the default outage {DEFAULT_OUTAGE_S[0]:g}–{DEFAULT_OUTAGE_S[1]:g} s is outside a "
                         f"{d:g}-s flight: moved to {a.outage[0]:g}–{a.outage[1]:g} s")
    elif "outage" in kinds:
        t0, t1 = a.outage
        if not t0 < t1:
            raise ValueError(f"--outage {t0:g},{t1:g}: not a window (T0 < T1)")
        if t0 >= d:
            raise ValueError(f"--outage {t0:g},{t1:g} starts at or after --duration {d:g} s: "
                             "no outage would happen; refused")
        if t1 > d:
            notes.append(f"the outage {t0:g}–{t1:g} s runs to the end of the {d:g}-s flight")
    if a.fog_at is None:
        a.fog_at = DEFAULT_FOG_AT_S
        if d < DEFAULT_SPAN_S and "fog" in kinds:
            a.fog_at = DEFAULT_FOG_AT_S / DEFAULT_SPAN_S * d
            notes.append(f"the default FOG failure at {DEFAULT_FOG_AT_S:g} s is outside a {d:g}-s flight: "
                         f"moved to {a.fog_at:g} s")
    elif "fog" in kinds and a.fog_at >= d:
        raise ValueError(f"--fog-at {a.fog_at:g} is at or after --duration {d:g} s: "
                         "no FOG failure would happen; refused")
    for kind, t in (("outage", a.outage[0]), ("fog", a.fog_at)):
        if kind in kinds and t < a.settle:
            notes.append(f"the {kind} fault starts at {t:g} s, before the statistics (--settle {a.settle:g} s)")
    return notes


def fly(kind: str, a: argparse.Namespace) -> dict:
    """One flight (ssis.basilisk.fly_leo); returns its pointing-error series and what the unit did."""
    unit = None
    if kind != "truth":
        table = ssis.Table.read(HERE.parent / "basilisk" / "table.toml")
        unit = UnitNav(
            table,
            st_outage=tuple(a.outage) if kind == "outage" else None,
            fog_failure=(a.fog_at, a.fog_index, a.fog_mode) if kind == "fog" else None,
            seed=a.seed,
            backend=a.backend,
            strict=a.strict,
        )
    out = fly_leo(unit, a.duration, a.task_ms)
    out["kind"] = kind
    if unit is not None:
        out["backend_report"] = unit.close()
        out["steps_before_aligned"] = unit.steps_before_aligned
        out["first_aligned_s"] = unit.first_aligned_s
        out["status_losses"] = unit.status_losses
        out["losses"] = unit.losses
        out["realignments"] = unit.realignments
        out["reconvergences"] = unit.reconvergences
        out["counters"] = {k: v for k, v in unit.backend.counters().items() if v}
    return out


def stats(x: np.ndarray) -> dict:
    return {"rms": np.sqrt(np.mean(x**2, axis=0)).tolist(), "3sigma": (np.abs(x.mean(axis=0)) + 3 * x.std(axis=0)).tolist(),
            "max": np.max(np.abs(x), axis=0).tolist()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=100.0, help="s")
    ap.add_argument("--settle", type=float, default=10.0, help="s before the statistics start")
    ap.add_argument("--scenarios", default="truth,unit,outage,fog")
    ap.add_argument("--outage", type=lambda s: [float(x) for x in s.split(",")], default=None,
                    help="T0,T1 s (default 30,90; in a flight shorter than 100 s, the same fractions of it)")
    ap.add_argument("--fog-index", type=int, default=1)
    ap.add_argument("--fog-at", type=float, default=None,
                    help="s (default 20; in a flight shorter than 100 s, the same fraction of it)")
    ap.add_argument("--fog-mode", default="dead", help="dead, or a bias step in deg/h")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--backend", choices=["in-process", "qemu"], default="in-process",
                    help="the unit: the flight core in-process, or the firmware in QEMU in lockstep")
    ap.add_argument("--strict", action="store_true",
                    help="stop the flight when the unit loses ALIGNED or CONVERGED after its first alignment")
    ap.add_argument("--task-ms", type=float, default=DT * 1e3,
                    help="the Basilisk task period, ms (UnitNav refuses anything but the unit's 5-ms step)")
    ap.add_argument("--json", type=Path, help="write the figures here (refused if it exists)")
    ap.add_argument("--max-added-3sigma-arcsec", type=float,
                    help="exit 1 when the pointing error the unit adds (nominal flight, 3σ) exceeds this")
    a = ap.parse_args()
    if a.fog_mode != "dead":
        a.fog_mode = float(a.fog_mode)
    if a.json is not None and a.json.exists():
        print(f"error: {a.json}: exists: refused", file=sys.stderr)
        return 2
    kinds = a.scenarios.split(",")
    try:
        notes = place_faults(a, kinds)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    report = {"duration_s": a.duration, "settle_s": a.settle, "backend": a.backend, "flights": {},
              "outage_s": a.outage, "fog_at_s": a.fog_at, "notes": notes}
    for n in notes:
        print(f"note: {n}")
    print(f"closed loop, unit: {a.backend}, {a.duration:.0f} s (Basilisk {a.task_ms:g}-ms task), after settling at {a.settle:.0f} s; arcsec, x y z")
    print(f"{'flight':<7} {'pointing error RMS':>26} {'added by the unit, RMS':>26} {'added, 3σ':>26} {'added, max':>26} {'unit attitude error 3σ':>26}  wall s")
    fmt = lambda v: " ".join(f"{x:8.2f}" for x in v)  # noqa: E731
    truth = None
    for kind in kinds:
        f = fly(kind, a)
        after = f["t_s"] >= a.settle
        if not after.any():
            print(f"error: --duration {a.duration} ends before --settle {a.settle}", file=sys.stderr)
            return 2
        p = stats(f["pointing_arcsec"][after])
        entry = {"pointing": p, "wall_s": f["wall_s"], "samples": int(after.sum())}
        cols = [fmt(p["rms"])]
        if kind == "truth":
            truth = f
        if truth is not None and kind != "truth":
            added = stats((f["pointing_arcsec"] - truth["pointing_arcsec"])[after])
            entry["added_by_unit"] = added
            cols += [fmt(added["rms"]), fmt(added["3sigma"]), fmt(added["max"])]
        else:
            cols += ["-", "-", "-"]
        if kind != "truth":
            n = stats(f["nav_err_arcsec"][after])
            entry["nav_error"] = n
            cols.append(fmt(n["3sigma"]))
        else:
            cols.append("-")
        print(f"{kind:<7} " + " ".join(f"{c:>26}" for c in cols) + f"  {f['wall_s']:.1f}")
        if "counters" in f:
            for k in ("steps_before_aligned", "first_aligned_s", "status_losses", "losses", "realignments",
                      "reconvergences", "counters"):
                entry[k] = f[k]
            if f["first_aligned_s"] is None:
                first = f"never aligned by the star tracker: flew truth all {f['steps_before_aligned']} steps"
            else:
                first = (f"first aligned by the star tracker at {f['first_aligned_s']:.3f} s "
                         f"(truth for the {f['steps_before_aligned']} steps before)")
            lost = ", ".join(f"{k} at {t:.2f} s" for t, k in f["losses"]) or "none"
            print(f"        unit: {first}; then status losses {f['status_losses']} ({lost}), "
                  f"re-alignments {f['realignments']}, re-convergences {f['reconvergences']}")
            print(f"        counters {f['counters']}")
            if f["backend_report"]:
                keep = [ln for ln in f["backend_report"].splitlines() if ln.split(":")[0] in KEEP]
                entry["backend_report"] = f["backend_report"]
                print("\n".join("        " + ln for ln in keep))
        report["flights"][kind] = entry
    if a.json is not None:
        with open(a.json, "x") as fh:
            json.dump(report, fh, indent=1)
    lim = a.max_added_3sigma_arcsec
    if lim is not None:
        worst = max(report["flights"].get("unit", {}).get("added_by_unit", {}).get("3sigma", [math.inf]))
        if worst > lim:
            print(f"FAIL: the pointing error the unit adds, 3σ {worst:.2f}″, exceeds {lim}″ (or no unit flight beside truth)",
                  file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
