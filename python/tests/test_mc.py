"""Monte Carlo campaigns on Dask (ssis.mc): a real cluster with a worker killed and
restarted, resume after an interrupted driver, replay, the report in Chromium, the
order-statistic bounds."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable, List

import numpy as np
import pytest

pytest.importorskip("dask.distributed")
pytest.importorskip("pyarrow")
pd = pytest.importorskip("pandas")

import ssis.mc as mc  # noqa: E402
from ssis.mc import report as mcr  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent


def same_bits(a: Any, b: Any) -> None:
    """Two results frames hold the same runs with the same bits (wall and CPU times aside)."""
    cols = [c for c in a.columns if c not in ("wall_s", "cpu_s")]
    assert sorted(cols) == sorted(c for c in b.columns if c not in ("wall_s", "cpu_s"))
    a, b = a.sort_values("run").reset_index(drop=True), b.sort_values("run").reset_index(drop=True)
    assert list(a["run"]) == list(b["run"])
    for c in cols:
        x, y = a[c].to_numpy(), b[c].to_numpy()
        if x.dtype.kind == "f":
            assert np.array_equal(x.view(np.int64), y.view(np.int64)), c
        else:
            assert list(x) == list(y), c


class Proc:
    """A `dask` command in its own process group (killed whole, as a machine dies)."""

    def __init__(self, *args: str, log: Path) -> None:
        self.log = open(log, "w")
        self.p = subprocess.Popen([str(BIN / "dask"), *args], stdout=self.log, stderr=subprocess.STDOUT,
                                  start_new_session=True)

    def kill(self) -> None:
        if self.p.poll() is None:
            os.killpg(self.p.pid, signal.SIGKILL)
        self.p.wait()
        self.log.close()


def test_real_cluster_worker_killed_and_restarted(tmp_path: Path, campaign: Callable[..., Path]) -> None:
    """`dask scheduler` and two `dask worker` processes on localhost; 200 runs; one worker
    killed (its whole process group, SIGKILL) once 60 runs are in, and started again:
    every run is in the Parquet exactly once, with the bits of the same campaign run in
    one local process."""
    c = campaign(200, 40.0)
    sched_file = tmp_path / "scheduler.json"
    procs: List[Proc] = []
    try:
        procs.append(Proc("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                          "--scheduler-file", str(sched_file), log=tmp_path / "scheduler.log"))
        deadline = time.monotonic() + 60
        while not sched_file.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        assert sched_file.exists(), (tmp_path / "scheduler.log").read_text()
        import json

        addr = json.loads(sched_file.read_text())["address"]

        def worker(n: int) -> Proc:
            return Proc("worker", addr, "--nthreads", "1", "--nworkers", "1", "--no-dashboard",
                        "--memory-limit", "1GiB", "--name", f"w{n}", log=tmp_path / f"worker{n}.log")

        procs += [worker(0), worker(1)]
        seen: List[int] = []
        killed = threading.Event()

        def on_result(r: dict) -> None:
            seen.append(int(r["run"]))
            if len(seen) == 60 and not killed.is_set():
                killed.set()
                procs[1].kill()
                procs.append(worker(2))

        out = mc.run(c, tmp_path / "dask", scheduler=addr, flush_rows=16, progress=False, on_result=on_result)
        assert killed.is_set(), "the campaign ended before a worker could be killed"
        assert out.errors == [], out.errors
        df = mc.load(tmp_path / "dask")
        runs = pd.concat([pd.read_parquet(p) for p in sorted((tmp_path / "dask/runs").glob("*.parquet"))])["run"]
        assert sorted(runs) == list(range(200)), "a run is missing or written twice"
        serial = mc.run(c, tmp_path / "serial", scheduler="serial", progress=False)
        assert serial.completed == 200
        same_bits(df, mc.load(tmp_path / "serial"))
    finally:
        for p in reversed(procs):
            p.kill()


def test_failing_run_in_a_batch_is_retried_alone(tmp_path: Path, campaign: Callable[..., Path],
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """Short runs travel in batches; one run that always fails (run 7, made to raise in a
    threaded in-process cluster) costs only itself: its batch's other runs are tried again
    one by one and written, run 7 is tried once in its batch and 1 + `retries` times alone,
    then listed with its error."""
    from dask.distributed import LocalCluster

    c = campaign(40, 40.0)
    native = mc._ssis
    real_one, real_many = native.mc_run, native.mc_runs
    tries: List[int] = []

    def one(text: str, origin: str, i: int, series_every: int = 0) -> Any:
        if i == 7:
            tries.append(i)
            raise RuntimeError("run 7 made to fail")
        return real_one(text, origin, i, series_every)

    def many(text: str, origin: str, runs: List[int], series_every: int = 0) -> Any:
        if 7 in runs:
            tries.append(7)
            raise RuntimeError("run 7 made to fail")
        return real_many(text, origin, runs, series_every)

    monkeypatch.setattr(native, "mc_run", one)
    monkeypatch.setattr(native, "mc_runs", many)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as cl:
        out = mc.run(c, tmp_path / "out", scheduler=cl.scheduler_address, retries=1, task_s=60.0,
                      progress=False)
    assert [e["run"] for e in out.errors] == [7], out.errors
    assert "run 7 made to fail" in out.errors[0]["error"]
    assert out.completed == 39
    assert sorted(mc.done_runs(tmp_path / "out")) == [i for i in range(40) if i != 7]
    assert len(tries) == 1 + 1 + 1, f"run 7 tried {len(tries)} times: once in its batch, then 1 + retries alone"


def test_resume_after_driver_killed(tmp_path: Path, campaign: Callable[..., Path]) -> None:
    """The driver (`ssis-mc run` on a local cluster) killed with SIGKILL mid-campaign, then
    started again: it skips the runs written, and every run is there exactly once, with the
    bits of an uninterrupted campaign."""
    c = campaign(120, 40.0)
    out = tmp_path / "out"
    cmd = [str(BIN / "ssis-mc"), "run", str(c), "--out", str(out), "--workers", "2", "--flush-rows", "8",
           "--no-progress", "--json"]
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and p.poll() is None:
        if len(list((out / "runs").glob("*.parquet"))) >= 3:
            break
        time.sleep(0.1)
    assert p.poll() is None, "the campaign ended before it could be interrupted"
    os.killpg(p.pid, signal.SIGKILL)
    p.wait()
    before = mc.done_runs(out)
    assert 0 < len(before) < 120
    q = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert q.returncode == 0, q.stderr
    import json

    o = json.loads(q.stdout.strip().splitlines()[-1])
    assert o["done_before"] == len(before) and o["completed"] == 120 - len(before)
    runs = pd.concat([pd.read_parquet(x) for x in sorted((out / "runs").glob("*.parquet"))])["run"]
    assert sorted(runs) == list(range(120))
    mc.run(c, tmp_path / "whole", scheduler="serial", progress=False)
    same_bits(mc.load(out), mc.load(tmp_path / "whole"))


def test_replay_gives_the_runs_bits(tmp_path: Path, campaign: Callable[..., Path]) -> None:
    c = campaign(6, 40.0)
    mc.run(c, tmp_path / "out", scheduler="serial", progress=False)
    df = mc.load(tmp_path / "out")
    r = mc.replay(c, 4)
    row = df[df["run"] == 4].iloc[0]
    for k, v in r["indices"].items():
        assert np.float64(v).view(np.int64) == np.float64(row[mc.INDEX + k]).view(np.int64), k
    q = subprocess.run([str(BIN / "ssis-mc"), "replay", str(c), "--run", "4", "--out", str(tmp_path / "out")],
                       capture_output=True, text=True)
    assert q.returncode == 0 and "the same bits" in q.stderr, q.stderr


def test_another_campaign_in_the_same_folder_is_refused(tmp_path: Path, campaign: Callable[..., Path]) -> None:
    mc.run(campaign(2, 40.0, name="a"), tmp_path / "out", scheduler="serial", progress=False)
    with pytest.raises(ValueError, match="another campaign"):
        mc.run(campaign(2, 40.0, name="b"), tmp_path / "out", scheduler="serial", progress=False)


def test_order_statistic_bounds() -> None:
    """The runs a 99.73 % bound needs, and the 95 % interval's coverage checked by drawing."""
    assert mcr.runs_needed(0.9973) == math.ceil(math.log(0.05) / math.log(0.9973))
    assert 1 - 0.9973 ** mcr.runs_needed(0.9973) >= 0.95 > 1 - 0.9973 ** (mcr.runs_needed(0.9973) - 1)
    rng = np.random.default_rng(5)
    n, p, trials = 200, 0.954, 2000
    xi = 1.6849  # the 95.4 % quantile of N(0, 1)
    hit = up = 0
    for _ in range(trials):
        q = mcr.quantile(rng.standard_normal(n), p)
        assert q.lo is not None and q.hi is not None and q.upper is not None
        hit += q.lo <= xi <= q.hi
        up += xi <= q.upper
    # distribution-free bounds are conservative: at least 95 % (binomial noise: 3σ ≈ 1.5 %)
    assert hit / trials >= 0.935 and up / trials >= 0.935, (hit, up)
    q = mcr.quantile(np.arange(200.0), 0.9973)
    assert q.upper is None and q.value == 199.0


CHROMIUM = Path("/usr/bin/chromium")


def test_report_renders_in_chromium(tmp_path: Path, campaign: Callable[..., Path]) -> None:
    """The report of a small campaign: self-contained (no script, no external reference),
    and in headless Chromium every table and SVG laid out with a size, no console message."""
    c = campaign(40, 40.0)
    mc.run(c, tmp_path / "out", scheduler="serial", progress=False)
    page_path = tmp_path / "report.html"
    q = subprocess.run([str(BIN / "ssis-mc"), "report", str(tmp_path / "out"), "--html", str(page_path)],
                       capture_output=True, text=True)
    assert q.returncode == 0, q.stderr
    assert "AKE_x" in q.stdout and "drivers" in q.stdout
    page = page_path.read_text()
    refs = page.replace('xmlns="http://www.w3.org/2000/svg"', "")
    for bad in ["<script", "src=", "<link", "url(", "@import", "http://", "https://"]:
        assert bad not in refs, f"the report is not self-contained: {bad}"
    r = mcr.report(tmp_path / "out")
    n_idx = len(r.budget)
    assert n_idx >= 9 and "ssis-mc replay" in page
    if not CHROMIUM.exists():
        if os.environ.get("CI"):
            pytest.fail("/usr/bin/chromium is missing (CI is set)")
        pytest.skip("/usr/bin/chromium is missing")
    probe = """<script>
(function () {
  var r = [];
  document.querySelectorAll('table').forEach(function (t, i) {
    var b = t.getBoundingClientRect();
    r.push('table ' + Math.round(b.width) + ' ' + Math.round(b.height) + ' ' + t.rows.length);
  });
  document.querySelectorAll('svg').forEach(function (s, i) {
    var b = s.getBoundingClientRect();
    r.push('svg ' + Math.round(b.width) + ' ' + Math.round(b.height) + ' ' + s.querySelectorAll('*').length);
  });
  var pre = document.createElement('pre');
  pre.id = 'layout-check';
  pre.textContent = r.join('\\n');
  document.body.appendChild(pre);
})();
</script>
"""
    probed = tmp_path / "probed.html"
    probed.write_text(page.replace("</body></html>", probe + "</body></html>"))
    p = subprocess.run([str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                        "--disable-background-networking", "--disable-component-update", "--disable-sync",
                        "--enable-logging=stderr", "--v=0", "--window-size=1280,2000", "--dump-dom",
                        f"--user-data-dir={tmp_path / 'profile'}", f"file://{probed}"],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    console = [ln for ln in p.stderr.splitlines() if ":CONSOLE" in ln or "Uncaught" in ln or "SyntaxError" in ln]
    assert console == [], console
    check = p.stdout.split('<pre id="layout-check">')[1].split("</pre>")[0].splitlines()
    tables = [ln.split() for ln in check if ln.startswith("table")]
    svgs = [ln.split() for ln in check if ln.startswith("svg")]
    # budget, drivers, sensitivity matrix, worst runs; one figure per index column
    assert len(tables) == 4 and len(svgs) == n_idx, check
    assert all(int(t[1]) > 100 and int(t[2]) > 20 for t in tables), tables
    assert tables[0][3] == str(n_idx + 1) and tables[3][3] == str(n_idx + 1)
    assert all(int(s[1]) == 360 and int(s[2]) == 200 and int(s[3]) > 20 for s in svgs), svgs


def test_doubled_fog_bias_tops_kde_of_its_axis(tmp_path: Path) -> None:
    """examples/basilisk/campaign-sensitivity.toml: FOG 2's bias 1σ twice the other FOGs',
    the tracker lost for 300 s before the observer has estimated the drift. The unit's rate
    is the least-squares solution of the four FOGs (X, Y, Z, −(1, 1, 1)/√3), whose
    pseudo-inverse puts FOG 2's bias on Z with weight 5/6 (1/6 on X and Y): so the size of
    FOG 2's bias must be KDE_z's first driver, beyond the chance level of the run count.
    X and Y are not asserted: FOG 2 weighs 1/6 there, under FOG 0's and FOG 1's 5/6."""
    c = ROOT / "examples/basilisk/campaign-sensitivity.toml"
    mc.run(c, tmp_path / "out", scheduler="serial", progress=False)
    df = mc.load(tmp_path / "out")
    assert len(df) == 200
    # the geometry the reason rests on
    import tomllib

    g = tomllib.loads((ROOT / "examples/basilisk/table.toml").read_text())["table"]["gamma_rad"]
    a, b = math.pi / 4, g - math.pi / 2
    h = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1],
                  [-math.cos(b) * math.cos(a), -math.cos(b) * math.sin(a), -math.sin(b)]])
    col = np.linalg.pinv(h)[:, 2]
    assert int(np.argmax(np.abs(col))) == 2 and abs(col[2] - 5 / 6) < 1e-9
    corr = mcr.sensitivity(df)
    top = mcr.drivers(corr)["KDE_10s_300s_z"]
    name, rho = top[0]
    assert name == "|table.fog[2].bias_rad_s|", top
    assert rho > mcr.chance_rho(len(df)), (rho, mcr.chance_rho(len(df)))
    # and the next driver is a clear step below it
    assert abs(top[1][1]) < rho / 2, top
