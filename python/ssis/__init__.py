"""ssis: the strapdown stellar-inertial attitude unit from Python.

A thin layer over the project's Rust libraries (the native module ``ssis._ssis``), the
same code the command lines run, so the numbers are the same:

- :class:`Table`: the calibration table (default, read, write, diff, fields by their
  documented names, docs/CALIBRATION.md);
- :class:`FlightCore`: the spacecraft unit's flight core, one 5-ms step at a time;
- :func:`replay`: a recorded log (docs/RECORDED-LOG.md) through the flight core, per-step
  arrays and the summary ``ssis-sim replay --json`` prints;
- :mod:`ssis.cal`: the calibration methods of ``ssis-cal`` (Allan deviation, turns, SINS);
- :mod:`ssis.lab`: the model lab of ``ssis-lab``;
- :mod:`ssis.basilisk`: the unit in closed loop with Basilisk (``pip install bsk``).

Errors are raised as :class:`SsisError` (a ``ValueError``) whose message names the file,
line and field, as the command line's does.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Sequence, Tuple, Union

import numpy as np

from . import _ssis
from ._ssis import SsisError, Table

__all__ = ["SsisError", "Table", "FlightCore", "QemuUnit", "Step", "Replay", "replay", "cal", "lab"]

PathLike = Union[str, "os.PathLike[str]"]


@dataclass
class Step:
    """What the unit output after one step (the output frame's content, unscaled)."""

    time_s: float
    """Unit time at the end of the integrated sample, s."""
    q: np.ndarray
    """Λ, the instrument frame in the inertial frame, scalar first."""
    rate_rad_s: np.ndarray
    """Body rate, drift removed, rad/s (instrument frame)."""
    drift_rad_s: np.ndarray
    """Drift estimate Δω, rad/s."""
    att_sigma_arcsec: np.ndarray
    """The estimator's attitude 1σ per axis, arcsec (inf before alignment)."""
    drift_sigma_rad_s: np.ndarray
    flags: int
    """Flag bits (docs/ICD.md, output frame)."""
    st_status: int
    fog_health: list
    fogs_used: int
    fdi: int
    parity_rad: float
    events: list = field(default_factory=list)
    """The unit's state changes sent after this step (its event log, as the event frames
    carry it, docs/ICD.md): dicts ``time_s``, ``seq``, ``event`` (e.g. ``"aligned"``,
    ``"isolated"``), ``a``, ``b``, ``details``. Both units give the same: :class:`QemuUnit`
    decodes the event frame the firmware sent after the step's output frame."""
    counters_moved: list = field(default_factory=list)
    """Counters that moved in this step, ``(name, increment)`` (e.g.
    ``("StFramesAccepted", 1)``). Empty from :class:`QemuUnit`."""


class _Unit:
    """What both units share: the step."""

    _native: Any

    def step(
        self,
        fog_dtheta_rad: Sequence[float],
        star: Optional[Tuple[float, Sequence[float]]] = None,
        temperature_degc: Optional[Sequence[float]] = None,
        star_valid: bool = True,
    ) -> Step:
        """One step: the four FOGs' raw increments over the step, rad (NaN: the sample does
        not arrive); ``star`` = ``(tag_t_s, q)``, a star-tracker solution arriving in this
        step (q the tracker's frame in the inertial frame, scalar first; ``tag_t_s`` the
        instant it holds, in unit time: step n ends at n × 5 ms)."""
        st = None if star is None else (float(star[0]), np.asarray(star[1], dtype=np.float64))
        temps = None if temperature_degc is None else np.asarray(temperature_degc, dtype=np.float64)
        return Step(**self._native.step(np.asarray(fog_dtheta_rad, dtype=np.float64), st, temps, star_valid))


class FlightCore(_Unit):
    """The spacecraft unit's flight core (four FOGs, star tracker, 5-ms steps), in-process.

    Each :meth:`step` encodes the FOG increments and the star-tracker solution into their
    frames on mock links and runs ``FlightCore::step``, as the simulator and the replay do.
    """

    def __init__(self, table: Optional[Table] = None) -> None:
        self._native = _ssis.FlightCore(table)

    @property
    def dt_s(self) -> float:
        """Step period, s (0.005)."""
        return self._native.dt_s

    @property
    def steps(self) -> int:
        return self._native.steps

    def align(self, q: Sequence[float]) -> None:
        """Sets the attitude to ``q`` (Λ, scalar first) and marks it aligned."""
        self._native.align(np.asarray(q, dtype=np.float64))

    def counters(self) -> dict:
        """The unit's counters by name."""
        return dict(self._native.counters())


class QemuUnit(_Unit):
    """The spacecraft firmware (``ssis-fw-test``) in QEMU, in lockstep, stepped like
    :class:`FlightCore` (the runner's driver, ``ssis-qemu``'s: each step's frames on the
    emulated UARTs, a STEP control frame, the output frame back). The runner compares every
    output frame with the same core run in-process; :meth:`close` returns its report.
    Needs ``qemu-system-arm`` and the thumb toolchain (the firmware is built if out of
    date). ``events`` are the firmware's (its event frames); ``counters_moved`` is always
    empty here (the output frame pages one counter at a time)."""

    def __init__(self, table: Optional[Table] = None, elf: Optional[PathLike] = None, steps: int = 0) -> None:
        self._native = _ssis.QemuUnit(table, None if elf is None else os.fspath(elf), steps)

    dt_s = 0.005

    def close(self) -> str:
        """Ends the run (END, QEMU exits) and returns the runner's report."""
        return self._native.close()

    def __enter__(self) -> "QemuUnit":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


@dataclass
class Replay:
    """A replay's per-output series and its summary."""

    t_s: np.ndarray
    q: np.ndarray
    """(n, 4), scalar first."""
    rate_rad_s: np.ndarray
    drift_rad_s: np.ndarray
    """(n, 3)."""
    flags: np.ndarray
    att_sigma_arcsec: np.ndarray
    att_err_arcsec: np.ndarray
    """(n, 3) against the log's truth; NaN where the log has none."""
    summary: dict
    """What ``ssis-sim replay --json`` prints under ``replay``."""
    conventions: dict
    """What it prints under ``conventions``."""
    report: str
    """The text report the command prints."""


def replay(
    log: Union[PathLike, Sequence[PathLike]],
    table: Optional[Table] = None,
    settle_s: float = 60.0,
    progress: Union[bool, Callable[[int, int], None], None] = None,
    decimate: int = 1,
    summary_only: bool = False,
) -> Replay:
    """Replays a recorded spacecraft log (one CSV, or link captures) through the flight core,
    as ``ssis-sim replay LOG [--table T] [--settle S] --json``. ``progress``: a callable
    ``(done, total)``, or ``True`` for a bar on standard error (the total is estimated from
    the file's size until the end).

    The arrays hold every output frame: 120 bytes a step, 2 GB for a 24-hour log.
    ``decimate=N`` keeps every N-th (the first, the (N+1)-th, ...); ``summary_only=True``
    keeps none (empty arrays). The summary, the conventions and the report are the whole
    log's either way, and a CSV log is read as it is replayed (docs/RECORDED-LOG.md,
    "Long logs"), so memory is the arrays' and little else."""
    if decimate < 1:
        raise ValueError(f"decimate must be 1 or more, not {decimate}")
    logs = [os.fspath(log)] if isinstance(log, (str, os.PathLike)) else [os.fspath(p) for p in log]
    cb = _bar("replay") if progress is True else (progress or None)
    d, summary, conv = _ssis.replay(logs, table, settle_s, cb, 0 if summary_only else decimate)
    return Replay(
        t_s=d["t_s"],
        q=d["q"].reshape(-1, 4),
        rate_rad_s=d["rate_rad_s"].reshape(-1, 3),
        drift_rad_s=d["drift_rad_s"].reshape(-1, 3),
        flags=d["flags"],
        att_sigma_arcsec=d["att_sigma_arcsec"].reshape(-1, 3),
        att_err_arcsec=d["att_err_arcsec"].reshape(-1, 3),
        summary=json.loads(summary),
        conventions=json.loads(conv),
        report=d["report"],
    )


def _bar(what: str) -> Callable[[int, int], None]:
    """A plain progress bar on standard error (tqdm's, when tqdm is installed)."""
    try:
        from tqdm import tqdm  # type: ignore

        bar: Any = None

        def tq(done: int, total: int) -> None:
            nonlocal bar
            if bar is None:
                bar = tqdm(total=total, desc=what, unit="step")
            bar.update(done - bar.n)
            if done >= total:
                bar.close()

        return tq
    except ImportError:
        import sys

        def plain(done: int, total: int) -> None:
            n = 30 * done // max(total, 1)
            sys.stderr.write(f"\r{what} [{'#' * n}{'.' * (30 - n)}] {done}/{total}")
            if done >= total:
                sys.stderr.write("\n")
            sys.stderr.flush()

        return plain


from . import cal, lab  # noqa: E402  (they import from this module)
