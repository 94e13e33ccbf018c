"""The unit's pointing budget by Monte Carlo, on Dask (docs/MONTE-CARLO.md).

A campaign is a TOML file (its format: docs/MONTE-CARLO.md); run ``i`` of it is a pure
function of (campaign, i), computed by the native module (``ssis._ssis.mc_run``: the
dispersions drawn, the flight simulated through the flight core, the ECSS error indices)
or, for ``loop = "closed"``, by :mod:`ssis.mc.closed` (Basilisk with
:class:`ssis.basilisk.UnitNav`). The same run gives the same bits on any worker, in any
order, so this module only distributes and keeps books:

- :func:`run`: the runs on a Dask cluster (a local cluster of processes by default, or any
  scheduler's address), written as they arrive to Parquet under ``out/`` (``runs/``: one
  row per run, its drawn parameters and indices; ``series/``: the optional decimated time
  series). A campaign started again on the same ``out/`` skips the runs already there;
  a run that fails, or whose worker dies, is retried, then listed with its error
  (``errors.jsonl``). Short runs travel in batches (one Dask task of about ``task_s``
  seconds); in-flight tasks are bounded (a window of futures), so is each worker's
  memory (``memory_limit``).
- :func:`load`: the results as a ``pandas.DataFrame``, one row per run.
- :func:`replay`: one run again, in this process, to the same bits.
- :mod:`ssis.mc.report`: the budget (percentiles with order-statistic bounds, histograms,
  CDFs, worst runs, sensitivity) as text and self-contained HTML.

Needs the ``mc`` extra: ``pip install 'ssis[mc]'`` (dask[distributed], pyarrow, pandas, tqdm).
"""

from __future__ import annotations

import collections
import contextlib
import hashlib
import itertools
import json
import os
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Deque, Dict, Iterable, Iterator, List, Optional, Sequence, Union

from .. import _ssis

__all__ = ["Campaign", "Outcome", "run", "run_one", "replay", "load", "load_series", "done_runs", "PARAM", "INDEX"]

PARAM = "param."
"""Column prefix of a drawn parameter in the results (``param.<name>``)."""
INDEX = "index."
"""Column prefix of an error index in the results (``index.<name>``, e.g. ``index.AKE_x``), arcsec."""

PathLike = Union[str, "os.PathLike[str]"]


@dataclass(frozen=True)
class Campaign:
    """A validated campaign: its text, the name errors give it, what the validation said."""

    text: str
    origin: str
    info: Dict[str, Any]
    """The native validation's summary (``mc_validate``): at least ``runs`` and ``loop``."""

    @staticmethod
    def read(path: PathLike) -> "Campaign":
        """Reads and validates a campaign file (errors name the file, line and key)."""
        p = Path(path)
        return Campaign.parse(p.read_text(), str(p))

    @staticmethod
    def parse(text: str, origin: str = "(campaign)") -> "Campaign":
        return Campaign(text, origin, json.loads(_ssis.mc_validate(text, origin)))

    @property
    def runs(self) -> int:
        return int(self.info["runs"])

    @property
    def loop(self) -> str:
        return str(self.info.get("loop", "open"))

    @property
    def digest(self) -> str:
        """SHA-256 of the campaign's text: the results of one campaign are never mixed with another's."""
        return hashlib.sha256(self.text.encode()).hexdigest()


def _campaign(c: Union[Campaign, PathLike]) -> Campaign:
    return c if isinstance(c, Campaign) else Campaign.read(c)


def run_one(text: str, origin: str, i: int, series_every: int = 0) -> Dict[str, Any]:
    """Run ``i`` of the campaign: ``run``, ``params``, ``indices``, optional ``series``,
    and the wall and CPU time it took on its worker's thread (``wall_s``, ``cpu_s``). What
    each worker calls."""
    t0, c0 = time.perf_counter(), time.thread_time()
    if _loop_of(text, origin) == "closed":
        from . import closed

        r = closed.run(text, origin, i, series_every)
    else:
        r = dict(_ssis.mc_run(text, origin, i, series_every))
    r["wall_s"] = time.perf_counter() - t0
    r["cpu_s"] = time.thread_time() - c0
    return r


_LOOPS: Dict[str, str] = {}


def run_batch(text: str, origin: str, runs: Sequence[int], series_every: int = 0) -> List[Dict[str, Any]]:
    """Runs ``runs`` of the campaign in turn: one Dask task for several short runs, so the
    scheduler's cost per task is paid once per batch. An open-loop batch reads the campaign
    (its scenario and table files) once; each run's ``wall_s`` and ``cpu_s`` are then the
    batch's shared equally."""
    if len(runs) == 1 or _loop_of(text, origin) == "closed":
        return [run_one(text, origin, i, series_every) for i in runs]
    t0, c0 = time.perf_counter(), time.thread_time()
    rs = [dict(r) for r in _ssis.mc_runs(text, origin, list(runs), series_every)]
    wall_s, cpu_s = (time.perf_counter() - t0) / len(rs), (time.thread_time() - c0) / len(rs)
    for r in rs:
        r["wall_s"], r["cpu_s"] = wall_s, cpu_s
    return rs


def _loop_of(text: str, origin: str) -> str:
    key = hashlib.sha256(text.encode()).hexdigest()
    if key not in _LOOPS:
        _LOOPS[key] = str(json.loads(_ssis.mc_validate(text, origin)).get("loop", "open"))
    return _LOOPS[key]


def _row(r: Dict[str, Any]) -> Dict[str, Any]:
    """One Parquet row: ``run``, ``param.*``, ``index.*``, the other scalars the run gave
    (``steps``, ``converged_at_s`` (NaN: never), ``digest``, …)."""
    row: Dict[str, Any] = {"run": int(r["run"])}
    for k, v in sorted(r.get("params", {}).items()):
        row[PARAM + k] = float(v)
    for k, v in sorted(r.get("indices", {}).items()):
        row[INDEX + k] = float(v)
    for k, v in r.items():
        if k in ("run", "params", "indices", "series"):
            continue
        if v is None and k.endswith("_s"):
            row[k] = float("nan")
        elif isinstance(v, (int, float, str, bool)):
            row[k] = v
    return row


def _series_rows(r: Dict[str, Any]) -> Optional[Dict[str, Any]]:
    """A run's series as columns: ``run``, then each array; an (N, 3) array ``a`` as
    ``a_x``, ``a_y``, ``a_z``."""
    import numpy as np

    s = r.get("series")
    if not s:
        return None
    cols: Dict[str, Any] = {}
    for k, v in s.items():
        a = np.asarray(v)
        if a.ndim == 2:
            for j in range(a.shape[1]):
                cols[f"{k}_{'xyz'[j] if a.shape[1] == 3 else j}"] = a[:, j]
        else:
            cols[k] = a
    n = len(next(iter(cols.values())))
    return {"run": np.full(n, int(r["run"]), dtype=np.int64), **cols}


class _Writer:
    """Appends rows to ``out/runs/`` (and series to ``out/series/``) as Parquet parts,
    each written under a temporary name and renamed, flushed every ``flush_rows`` rows or
    ``flush_s`` seconds."""

    def __init__(self, out: Path, flush_rows: int, flush_s: float) -> None:
        self.out, self.flush_rows, self.flush_s = out, max(1, flush_rows), flush_s
        self.session = uuid.uuid4().hex[:8]
        self.seq = 0
        self.rows: List[Dict[str, Any]] = []
        self.series: List[Dict[str, Any]] = []
        self.last = time.monotonic()
        for d in ("runs", "series"):
            (out / d).mkdir(parents=True, exist_ok=True)
            for t in (out / d).glob("*.tmp"):
                t.unlink()  # a part a killed session did not finish

    def add(self, r: Dict[str, Any]) -> None:
        self.rows.append(_row(r))
        s = _series_rows(r)
        if s is not None:
            self.series.append(s)
        if len(self.rows) >= self.flush_rows or time.monotonic() - self.last >= self.flush_s:
            self.flush()

    def flush(self) -> None:
        import pandas as pd  # type: ignore[import-untyped,unused-ignore]

        self.last = time.monotonic()
        if not self.rows:
            return
        name = f"part-{self.session}-{self.seq:05d}.parquet"
        self.seq += 1
        # Series first: a run is done when its row is written, and then its series is too.
        if self.series:
            frame = pd.concat([pd.DataFrame(s) for s in self.series], ignore_index=True)
            _write(frame, self.out / "series" / name)
        _write(pd.DataFrame(self.rows), self.out / "runs" / name)
        self.rows, self.series = [], []


def _write(frame: Any, path: Path) -> None:
    tmp = path.with_name(path.name + ".tmp")
    frame.to_parquet(tmp, index=False, engine="pyarrow")
    os.replace(tmp, path)


def _parts(out: Path, what: str) -> List[Path]:
    return sorted((out / what).glob("part-*.parquet"))


def load(out: PathLike) -> Any:
    """The results under ``out/`` as a ``pandas.DataFrame``, one row per run, by run."""
    import pandas as pd  # type: ignore[import-untyped,unused-ignore]

    parts = _parts(Path(out), "runs")
    if not parts:
        raise FileNotFoundError(f"{out}: no results (runs/part-*.parquet)")
    df = pd.concat([pd.read_parquet(p) for p in parts], ignore_index=True)
    return df.drop_duplicates("run").sort_values("run", kind="stable").reset_index(drop=True)


def load_series(out: PathLike, run_index: Optional[int] = None) -> Any:
    """The decimated time series under ``out/series/`` (long format: ``run``, ``t_s``, …)."""
    import pandas as pd  # type: ignore[import-untyped,unused-ignore]

    parts = _parts(Path(out), "series")
    if not parts:
        raise FileNotFoundError(f"{out}: no time series (run with series_every > 0)")
    filters = None if run_index is None else [("run", "==", int(run_index))]
    return pd.concat([pd.read_parquet(p, filters=filters) for p in parts], ignore_index=True)


def done_runs(out: PathLike) -> set:
    """The runs already written under ``out/``."""
    import pyarrow.parquet as pq  # type: ignore[import-untyped,unused-ignore]

    done: set = set()
    for p in _parts(Path(out), "runs"):
        done.update(int(x) for x in pq.read_table(p, columns=["run"]).column("run").to_pylist())
    return done


@dataclass
class Outcome:
    """What :func:`run` did."""

    out: Path
    campaign: Campaign
    done_before: int
    """Runs found already done under ``out/`` (skipped)."""
    completed: int = 0
    """Runs completed in this session."""
    errors: List[Dict[str, Any]] = field(default_factory=list)
    """Runs that failed after their retries: ``run``, ``error``."""
    wall_s: float = 0.0
    workers: int = 0
    """Worker threads the cluster had at the start."""
    steps: int = 0
    """Unit steps flown by the runs completed in this session."""
    run_wall_s: float = 0.0
    """The completed runs' wall times on their workers, summed."""
    run_cpu_s: float = 0.0
    """The completed runs' CPU times on their workers' threads, summed."""

    @property
    def steps_per_s(self) -> float:
        """Unit steps per second of this session's wall time, end to end (all workers)."""
        return self.steps / self.wall_s if self.wall_s > 0 else 0.0

    def __str__(self) -> str:
        s = (f"{self.completed} runs in {self.wall_s:.1f} s on {self.workers} workers "
             f"({self.done_before} already done), {len(self.errors)} failed; results in {self.out}")
        if self.steps:
            s += (f"\n{self.steps} unit steps: {self.steps_per_s / 1e6:.3f} M steps/s end to end, "
                  f"{self.steps / max(self.run_wall_s, 1e-9) / 1e6:.3f} M steps/s per worker in the runs, "
                  f"{self.steps / max(self.run_cpu_s, 1e-9) / 1e6:.3f} M per CPU second")
        for e in self.errors[:10]:
            s += f"\n  run {e['run']}: {e['error']}"
        return s


def _selection(c: Campaign, runs: Union[None, int, range, Sequence[int]]) -> List[int]:
    if runs is None:
        sel: Iterable[int] = range(c.runs)
    elif isinstance(runs, int):
        sel = range(min(runs, c.runs))
    else:
        sel = runs
    out = [int(i) for i in sel]
    bad = [i for i in out if not 0 <= i < c.runs]
    if bad:
        raise ValueError(f"runs {bad[:5]}: the campaign has runs 0 … {c.runs - 1}")
    return out


class _Progress:
    """A tqdm bar when tqdm is there (and ``show``), else a line every 10 %; the expected
    end as a clock time in both."""

    def __init__(self, total: int, show: bool) -> None:
        self.total, self.n, self.t0, self.bar = total, 0, time.monotonic(), None
        self.show = show
        self.next_line = 0.1
        if show:
            try:
                from tqdm import tqdm  # type: ignore[import-untyped,unused-ignore]

                self.bar = tqdm(total=total, unit="run", smoothing=0.05, file=sys.stderr)
            except ImportError:
                pass

    def end_clock(self) -> str:
        el = time.monotonic() - self.t0
        if self.n == 0:
            return "?"
        return time.strftime("%H:%M:%S", time.localtime(time.time() + el / self.n * (self.total - self.n)))

    def update(self, failed: int) -> None:
        self.n += 1
        if self.bar is not None:
            self.bar.set_postfix_str(f"ends ~{self.end_clock()}, {failed} failed", refresh=False)
            self.bar.update(1)
        elif self.show and self.total and self.n / self.total >= self.next_line:
            self.next_line += 0.1
            print(f"ssis-mc: {self.n}/{self.total} runs, {failed} failed, ends ~{self.end_clock()}", file=sys.stderr)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _meta(out: Path, c: Campaign) -> None:
    """Keeps the campaign beside its results; refuses another campaign's results folder."""
    out.mkdir(parents=True, exist_ok=True)
    meta = out / "campaign.json"
    if meta.exists():
        old = json.loads(meta.read_text())
        if old.get("sha256") != c.digest:
            raise ValueError(f"{out} holds the results of another campaign ({old.get('origin')}, "
                             f"sha256 {str(old.get('sha256'))[:12]}…): give another --out")
        return
    (out / "campaign.toml").write_text(c.text)
    meta.write_text(json.dumps({"origin": c.origin, "sha256": c.digest, "runs": c.runs, "loop": c.loop}, indent=1) + "\n")


def run(
    campaign: Union[Campaign, PathLike],
    out: PathLike,
    scheduler: Optional[str] = None,
    workers: Optional[int] = None,
    memory_limit: str = "2GiB",
    runs: Union[None, int, range, Sequence[int]] = None,
    series_every: int = 0,
    retries: int = 2,
    window: Optional[int] = None,
    task_s: float = 1.0,
    flush_rows: int = 256,
    flush_s: float = 5.0,
    progress: bool = True,
    on_result: Optional[Callable[[Dict[str, Any]], None]] = None,
) -> Outcome:
    """Runs a campaign (or ``runs`` of it: a count, a range or indices) and writes the
    results under ``out/``, skipping runs already there.

    ``scheduler``: ``None`` for a local cluster of ``workers`` processes (default: the
    machine's cores; each one thread, at most ``memory_limit``), a Dask scheduler's
    address (``tcp://host:8786``), or ``"serial"``: every run in this process, no Dask.
    ``retries``: how often a failed run (an error, or its worker died) is tried again
    before it is listed in :attr:`Outcome.errors`. ``window``: tasks in flight at once
    (default: 2 per worker thread). ``task_s``: short runs go to a worker
    in batches of about this many seconds (sized from the runs already back; a failed batch's
    runs are tried again one by one), so Dask's cost per task does not eat the workers' time.
    ``series_every``: keep every n-th step of each run's
    time series (0: none). ``on_result`` is called in this process with each finished
    run's result (the test's hook).
    """
    if not task_s > 0 or task_s == float("inf"):
        raise ValueError(f"task_s: seconds per task must be positive and finite, got {task_s!r}")
    c = _campaign(campaign)
    outp = Path(out)
    _meta(outp, c)
    done = done_runs(outp)
    todo = [i for i in _selection(c, runs) if i not in done]
    errors_path = outp / "errors.jsonl"
    errors_path.write_text("")
    o = Outcome(outp, c, done_before=len(done))
    writer = _Writer(outp, flush_rows, flush_s)
    bar = _Progress(len(todo), progress)
    t0 = time.perf_counter()

    def finished(i: int, r: Optional[Dict[str, Any]], err: Optional[BaseException]) -> None:
        if err is not None:
            e = {"run": i, "error": f"{type(err).__name__}: {err}"}
            o.errors.append(e)
            with open(errors_path, "a") as f:
                f.write(json.dumps(e) + "\n")
        else:
            assert r is not None
            writer.add(r)
            o.completed += 1
            o.steps += int(r.get("steps", 0))
            o.run_wall_s += float(r.get("wall_s", 0.0))
            o.run_cpu_s += float(r.get("cpu_s", 0.0))
            if on_result is not None:
                on_result(r)
        bar.update(len(o.errors))

    try:
        if scheduler == "serial":
            o.workers = 1
            for i in todo:
                r, err = None, None
                for _ in range(retries + 1):
                    try:
                        r, err = run_one(c.text, c.origin, i, series_every), None
                        break
                    except Exception as e:  # listed with the run, as a worker's would be
                        err = e
                finished(i, r, err)
        else:
            _dask(c, todo, scheduler, workers, memory_limit, series_every, retries, window, task_s, o, finished)
    finally:
        writer.flush()
        bar.close()
        o.wall_s = time.perf_counter() - t0
    return o


def _dask(c: Campaign, todo: List[int], scheduler: Optional[str], workers: Optional[int], memory_limit: str,
          series_every: int, retries: int, window: Optional[int], task_s: float, o: Outcome,
          finished: Callable[[int, Optional[Dict[str, Any]], Optional[BaseException]], None]) -> None:
    import dask
    from dask.distributed import Client, LocalCluster

    cluster = None
    quiet: Any = contextlib.nullcontext()
    if scheduler is None:
        # The local cluster is tuned for runs of whole CPU seconds, a user's own cluster keeps
        # its configuration. Dask's nanny starts each worker with MALLOC_TRIM_THRESHOLD_ set,
        # which also fixes glibc's mmap threshold: every large buffer of every run is then
        # mapped, faulted in and unmapped again; a run frees its memory when it ends. And a
        # worker's event loop wakes every 10 ms to sample the running task's stack (Dask's
        # profiler) and every 20 ms for its tick: with one worker a core, these wake-ups take
        # the runs' own CPU.
        env = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}) or {})
        env.pop("MALLOC_TRIM_THRESHOLD_", None)
        quiet = dask.config.set({
            "distributed.nanny.pre-spawn-environ": env,
            "distributed.worker.profile.enabled": False,
            "distributed.admin.tick.interval": "1s",
            "distributed.admin.system-monitor.interval": "2s",
            "distributed.worker.memory.monitor-interval": "500ms",
        })
    with quiet:
        if scheduler is None:
            cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                                   memory_limit=memory_limit, dashboard_address=None)
            client = Client(cluster)
        else:
            client = Client(scheduler)
        _drive(c, todo, client, series_every, retries, window, task_s, o, finished, cluster)


def _drive(c: Campaign, todo: List[int], client: Any, series_every: int, retries: int, window: Optional[int],
           task_s: float, o: Outcome,
           finished: Callable[[int, Optional[Dict[str, Any]], Optional[BaseException]], None],
           cluster: Any) -> None:
    from dask.distributed import as_completed

    try:
        o.workers = sum(client.nthreads().values()) or 1
        width = window or max(4, 2 * o.workers)
        tag = f"ssis-mc-{c.digest[:10]}-{uuid.uuid4().hex[:6]}"
        which: Dict[Any, List[int]] = {}
        ac = as_completed()
        left: Deque[int] = collections.deque(todo)
        alone: Deque[int] = collections.deque()  # runs of a failed batch, tried one by one
        timed = [0, 0.0]  # runs returned, their wall seconds: the batch size's estimate
        seq = itertools.count()

        def submit() -> bool:
            if alone:
                batch = [alone.popleft()]
            elif left:
                k = 1
                if timed[0]:
                    k = int(task_s / max(timed[1] / timed[0], 1e-6))
                    k = max(1, min(k, len(left) // (4 * o.workers)))
                batch = [left.popleft() for _ in range(min(k, len(left)))]
            else:
                return False
            key = f"{tag}-{batch[0]}-{len(batch)}-{next(seq)}"
            f = client.submit(run_batch, c.text, c.origin, batch, series_every, key=key, pure=False,
                              retries=retries if len(batch) == 1 else 0)
            which[f.key] = batch
            ac.add(f)
            return True

        while len(which) < width and submit():
            pass
        for f in ac:
            batch = which.pop(f.key)
            try:
                rs, err = f.result(), None
            except Exception as e:  # the run's error after its retries, or KilledWorker
                rs, err = None, e
            f.release()
            if rs is not None:
                for i, r in zip(batch, rs):
                    timed[0] += 1
                    timed[1] += float(r.get("wall_s", 0.0))
                    finished(i, r, None)
            elif len(batch) == 1:
                finished(batch[0], None, err)
            else:
                alone.extend(batch)  # which run failed is found by trying each alone
            while len(which) < width and submit():
                pass
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def replay(campaign: Union[Campaign, PathLike], run_index: int, series_every: int = 0) -> Dict[str, Any]:
    """Run ``run_index`` of the campaign again, in this process: the same bits as in the
    results (``params``, ``indices``, ``series``)."""
    c = _campaign(campaign)
    _selection(c, [run_index])
    return run_one(c.text, c.origin, run_index, series_every)


def replay_command(campaign_path: str, run_index: int) -> str:
    """The one-line command that replays a run."""
    return f"ssis-mc replay {_quote(campaign_path)} --run {run_index}"


def _quote(s: str) -> str:
    import shlex

    return shlex.quote(s)
