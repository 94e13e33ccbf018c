#!/usr/bin/env python3
"""The model lab's loop from Python, on a simulated session with a hidden effect.

A thermal-chamber session is simulated with an effect the starting model lacks (the
`thermal` preset hides a temperature-rate effect); the loop then reads it, compares the
model with it, diagnoses what is missing, adds the most significant candidate while the
held-out error falls, and exports the calibration table the firmware loads. The same
steps as `ssis-lab init/compare/diagnose/add/export` (docs/LAB.md), with the same numbers.

    python3 lab_loop.py [--preset thermal] [--out DIR] [--rounds 3]

Exits non-zero if the held-out error does not fall.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import ssis
from ssis import lab


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="thermal", help="magnetic, thermal, asymmetry, sin2psi, flight or replay")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--rounds", type=int, default=3, help="at most this many terms added")
    ap.add_argument("--out", type=Path, help="folder for the session, models and table (new; default: a temporary one)")
    a = ap.parse_args()
    out = a.out or Path(tempfile.mkdtemp(prefix="ssis-lab-loop-"))
    out.mkdir(parents=True, exist_ok=a.out is None)
    session_path = out / f"{a.preset}.csv"
    floor = lab.simulate(a.preset, session_path, seed=a.seed)
    print(f"simulated {session_path} (white-noise floor {floor:.4f} °/h, one effect hidden)")

    session = lab.Session.read(session_path)  # read once; every pass below works in memory
    print(f"read {len(session)} samples, columns {', '.join(session.names)}")
    model = lab.Model.init(["bias", "scale_factor", "misalignment"])
    models = [model]
    c = lab.compare(model, session)
    print("compare v1: residual RMS per FOG, °/h:", " ".join(f"{f['rms_residual_deg_h']:.4f}" for f in c["fogs"]))

    for _ in range(a.rounds):
        d = lab.diagnose(model, session)
        best = next((x for x in d.candidates if x.significant), None)
        shown = ", ".join(f"{x.name} p={x.p:.2g} removes {x.removed_deg_h:.4f} °/h" for x in d.candidates[:3])
        print(f"diagnose v{model.version}: {shown}")
        if best is None:
            print("  nothing significant left: the model explains the session down to its noise")
            break
        model, added = lab.add(model, best.name, session)
        models.append(model)
        print(f"add {best.name}: held-out RMS {added['pooled_before_deg_h']:.4f} -> {added['pooled_after_deg_h']:.4f} °/h")

    history = lab.held_out(models, session)
    print("history (held-out RMS, pooled °/h):", " -> ".join(f"v{m.version} {h[0]:.4f}" for m, h in zip(models, history)))
    for m in models:
        m.write(out / f"model.v{m.version}.toml")
    table, ex, _text = lab.export(model, model_name=str(out / f"model.v{model.version}.toml"))
    table.write(out / "table.toml")
    print(f"export: applied onboard {', '.join(ex['applied_onboard'])}; wrote {out / 'table.toml'} (revision {table.revision})")
    lab.report(model, session, out / "report.html", versions=models)
    print(f"wrote {out / 'report.html'}")
    if not history[-1][0] < history[0][0]:
        print("FAIL: the held-out error did not fall", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
