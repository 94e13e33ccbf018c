"""``ssis-mc``: run a Monte Carlo campaign, report its budget, replay one run (docs/MONTE-CARLO.md).

    ssis-mc validate campaign.toml
    ssis-mc run campaign.toml --out results/ [--scheduler tcp://host:8786 | --workers 2]
    ssis-mc report results/ [--html report.html]
    ssis-mc replay campaign.toml --run 1234 [--out results/]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
from pathlib import Path
from typing import Iterator, List, Optional, Sequence, Union

from .. import SsisError


@contextlib.contextmanager
def _stdout_to_stderr(on: bool) -> Iterator[None]:
    """With ``--json``, standard output carries the one JSON document only: what the runs
    print meanwhile (Basilisk's log lines, from C++ and from the Dask workers this process
    starts, which inherit its descriptors) goes to standard error."""
    if not on:
        yield
        return
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def _runs(s: Optional[str]) -> Union[None, int, range]:
    """``N`` (the first N runs) or ``A:B`` (runs A … B-1)."""
    if s is None:
        return None
    if ":" in s:
        a, b = s.split(":", 1)
        return range(int(a or 0), int(b))
    return int(s)


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="ssis-mc", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    v = sub.add_parser("validate", help="check a campaign file and print what it runs")
    v.add_argument("campaign")
    r = sub.add_parser("run", help="run a campaign on Dask; results as Parquet under --out (resumes)")
    r.add_argument("campaign")
    r.add_argument("--out", required=True, help="results folder (a campaign started again there skips its done runs)")
    r.add_argument("--scheduler", help="a Dask scheduler's address (tcp://host:8786), or 'serial' (this process, "
                   "no Dask); default: a local cluster of --workers processes")
    r.add_argument("--workers", type=int, help="local cluster: worker processes (default: the cores)")
    r.add_argument("--memory-limit", default="2GiB", help="local cluster: memory per worker (default 2GiB)")
    r.add_argument("--runs", help="N: the first N runs; A:B: runs A … B-1 (default: all)")
    r.add_argument("--series-every", type=int, default=0, help="keep every N-th step's series (0: none)")
    r.add_argument("--retries", type=int, default=2, help="tries again of a failed run (default 2)")
    r.add_argument("--window", type=int, help="tasks in flight at once (default: 2 per worker thread)")
    r.add_argument("--task-s", type=float, default=1.0,
                   help="short runs go to a worker in batches of about this many seconds (default 1)")
    r.add_argument("--flush-rows", type=int, default=256, help="rows per Parquet part at most (default 256)")
    r.add_argument("--no-progress", action="store_true", help="no progress bar")
    r.add_argument("--json", action="store_true", help="print the outcome as JSON")
    p = sub.add_parser("report", help="the budget of a results folder (text; --html: the page)")
    p.add_argument("out")
    p.add_argument("--html", help="write the self-contained HTML report here")
    p.add_argument("--campaign", help="the campaign file's name in the replay commands (default: OUT/campaign.toml)")
    p.add_argument("--json", action="store_true", help="print the budget table as JSON")
    y = sub.add_parser("replay", help="one run again, in this process (the same bits as in the results)")
    y.add_argument("campaign")
    y.add_argument("--run", type=int, required=True)
    y.add_argument("--series-every", type=int, default=0)
    y.add_argument("--out", help="a results folder: also check the run against its row there")
    y.add_argument("--json", action="store_true")
    return ap


def main(argv: Optional[Sequence[str]] = None) -> int:
    a = _parser().parse_args(argv)
    try:
        return _main(a)
    except (SsisError, ValueError, FileNotFoundError) as e:
        print(f"ssis-mc {a.cmd}: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("ssis-mc: interrupted; the runs written so far are kept (run again to resume)", file=sys.stderr)
        return 130


def _main(a: argparse.Namespace) -> int:
    from . import INDEX, PARAM, Campaign, load, replay, run

    if a.cmd == "validate":
        c = Campaign.read(a.campaign)
        print(json.dumps(c.info, indent=1))
        return 0
    if a.cmd == "run":
        with _stdout_to_stderr(a.json):
            o = run(a.campaign, a.out, scheduler=a.scheduler, workers=a.workers, memory_limit=a.memory_limit,
                    runs=_runs(a.runs), series_every=a.series_every, retries=a.retries, window=a.window,
                    task_s=a.task_s, flush_rows=a.flush_rows, progress=not a.no_progress)
        if a.json:
            print(json.dumps({"out": str(o.out), "completed": o.completed, "done_before": o.done_before,
                              "errors": o.errors, "wall_s": o.wall_s, "workers": o.workers, "steps": o.steps,
                              "steps_per_s": o.steps_per_s, "run_wall_s": o.run_wall_s,
                              "run_cpu_s": o.run_cpu_s}))
        else:
            print(o)
        return 1 if o.errors else 0
    if a.cmd == "report":
        from .report import report

        r = report(a.out, a.campaign)
        if a.json:
            print(r.budget.to_json(orient="records"))
        else:
            print(r.text())
        if a.html:
            Path(a.html).write_text(r.html())
            print(f"wrote {a.html}", file=sys.stderr)
        return 0
    if a.cmd == "replay":
        with _stdout_to_stderr(a.json):
            res = replay(a.campaign, a.run, a.series_every)
        if a.json:
            res = {k: (v if k != "series" else {s: list(x) for s, x in v.items()}) for k, v in res.items()}
            print(json.dumps(res))
        else:
            print(f"run {a.run}")
            for k, v in sorted(res.get("params", {}).items()):
                print(f"  {PARAM}{k} = {v!r}")
            for k, v in sorted(res.get("indices", {}).items()):
                print(f"  {INDEX}{k} = {v!r} arcsec")
        if a.out:
            df = load(a.out)
            row = df[df["run"] == a.run]
            if row.empty:
                print(f"run {a.run} is not in {a.out}", file=sys.stderr)
                return 1
            diff: List[str] = []
            for k, v in res.get("indices", {}).items():
                w = float(row[INDEX + k].iloc[0])
                if not (w == v or (math.isnan(w) and math.isnan(v))):
                    diff.append(f"{k}: {v!r} here, {w!r} in {a.out}")
            if diff:
                print("differs from the results: " + "; ".join(diff), file=sys.stderr)
                return 1
            print(f"the same bits as run {a.run} in {a.out}", file=sys.stderr)
        return 0
    raise AssertionError(a.cmd)


if __name__ == "__main__":
    sys.exit(main())
