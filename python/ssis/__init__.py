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
line and field, as the command line's does, or the argument and the shape it needs.

``Table``, ``FlightCore``, ``lab.Session`` and ``lab.Model`` pickle and copy (a pickled
core carries its whole state and continues bit for bit), so runs can be forked or sent to
worker processes.
"""

from __future__ import annotations

import json
import os
import copy as _copy
import html as _html
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from . import _ssis
from ._ssis import SsisError, Table

__all__ = ["SsisError", "Table", "FlightCore", "QemuUnit", "Step", "Run", "Replay", "replay", "cal", "lab", "__version__"]

__version__: str = _ssis.__version__

# Bits of the output frame's `flags` and `st_status` (docs/ICD.md).
_FLAG_ST_IN_USE, _FLAG_DEGRADED, _FLAG_CONVERGED, _FLAG_FDI_ALARM = 1 << 0, 1 << 1, 1 << 2, 1 << 6
_ST_ALIGNED, _ST_OUTAGE, _ST_VALID = 1 << 2, 1 << 4, 1 << 7


def _pandas() -> Any:
    try:
        import pandas  # type: ignore[import-untyped,unused-ignore]
    except ImportError as e:  # pandas is optional
        raise ImportError("to_pandas() needs pandas (pip install pandas)") from e
    return pandas


def _columns(arrays: Dict[str, np.ndarray], names: Mapping[str, Sequence[str]]) -> Dict[str, np.ndarray]:
    """One column per scalar: an (n, k) array ``a`` becomes ``a_<name>`` for each of
    ``names[a]`` (``q0`` … ``q3`` for the quaternion)."""
    out: Dict[str, np.ndarray] = {}
    for key, a in arrays.items():
        if a.ndim == 1:
            out[key] = a
        else:
            for j, suffix in enumerate(names[key]):
                out[suffix if key == "q" else f"{key}_{suffix}"] = a[:, j]
    return out


_XYZ = ("x", "y", "z")
_WIDE = {
    "q": ("q0", "q1", "q2", "q3"),
    "rate_rad_s": _XYZ,
    "drift_rad_s": _XYZ,
    "att_sigma_arcsec": _XYZ,
    "att_err_arcsec": _XYZ,
    "drift_sigma_rad_s": _XYZ,
    "fog_health": ("fog0", "fog1", "fog2", "fog3"),
}

PathLike = Union[str, "os.PathLike[str]"]


@dataclass(repr=False)
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
    """Flag bits (docs/ICD.md, output frame); by name: :attr:`converged`, :attr:`degraded`,
    :attr:`fdi_alarm`, :attr:`star_in_use`."""
    st_status: int
    """Star-tracker status bits (docs/ICD.md); by name: :attr:`aligned`, :attr:`attitude_valid`, :attr:`st_outage`."""
    fog_health: List[int]
    """Per FOG, its health bits (docs/ICD.md, ``health``)."""
    fogs_used: int
    fdi: int
    parity_rad: float
    events: List[Dict[str, Any]] = field(default_factory=list)
    """The unit's state changes sent after this step (its event log, as the event frames
    carry it, docs/ICD.md): dicts ``time_s``, ``seq``, ``event`` (e.g. ``"aligned"``,
    ``"isolated"``), ``a``, ``b``, ``details``. Both units give the same: :class:`QemuUnit`
    decodes the event frame the firmware sent after the step's output frame."""
    counters_moved: List[Tuple[str, int]] = field(default_factory=list)
    """Counters that moved in this step, ``(name, increment)`` (e.g.
    ``("StFramesAccepted", 1)``). Empty from :class:`QemuUnit`."""

    @property
    def aligned(self) -> bool:
        """``st_status`` bit 2: the attitude has been aligned by the star tracker and the
        mounting check found no FOG at odds with the tracker (docs/ICD.md)."""
        return bool(self.st_status & _ST_ALIGNED)

    @property
    def attitude_valid(self) -> bool:
        """``st_status`` bit 7: the attitude is good to use, the unit's one derived validity
        (aligned, converged, no parity alarm, built-in test passed, a sample integrated in
        this step, no held increment, no resume awaiting confirmation; docs/ICD.md)."""
        return bool(self.st_status & _ST_VALID)

    @property
    def st_outage(self) -> bool:
        """``st_status`` bit 4: no accepted star-tracker frame for more than 2 s."""
        return bool(self.st_status & _ST_OUTAGE)

    @property
    def converged(self) -> bool:
        """``flags`` bit 2: the observer has converged."""
        return bool(self.flags & _FLAG_CONVERGED)

    @property
    def degraded(self) -> bool:
        """``flags`` bit 1: degraded (fewer FOGs, or a fault being handled)."""
        return bool(self.flags & _FLAG_DEGRADED)

    @property
    def fdi_alarm(self) -> bool:
        """``flags`` bit 6: the parity check's alarm."""
        return bool(self.flags & _FLAG_FDI_ALARM)

    @property
    def star_in_use(self) -> bool:
        """``flags`` bit 0: the star tracker is in use."""
        return bool(self.flags & _FLAG_ST_IN_USE)

    def __repr__(self) -> str:
        q = ", ".join(f"{v:.9f}" for v in self.q)
        ev = f", events={[e['event'] for e in self.events]}" if self.events else ""
        return (
            f"Step(time_s={self.time_s:.3f}, q=[{q}], flags=0x{self.flags:02x}, "
            f"st_status=0x{self.st_status:02x}, aligned={self.aligned}, valid={self.attitude_valid}, converged={self.converged}, "
            f"fogs_used=0b{self.fogs_used:04b}{ev})"
        )

    def _repr_html_(self) -> str:
        return f"<code>{_html.escape(repr(self))}</code>"


@dataclass(repr=False)
class Run:
    """What :meth:`FlightCore.run` returns: one row per step."""

    time_s: np.ndarray
    q: np.ndarray
    """(n, 4), scalar first."""
    rate_rad_s: np.ndarray
    drift_rad_s: np.ndarray
    att_sigma_arcsec: np.ndarray
    drift_sigma_rad_s: np.ndarray
    """(n, 3)."""
    parity_rad: np.ndarray
    flags: np.ndarray
    st_status: np.ndarray
    fog_health: np.ndarray
    """(n, 4)."""
    fogs_used: np.ndarray
    fdi: np.ndarray
    events: List[Dict[str, Any]]
    """As :attr:`Step.events`, each with ``step``: its row."""

    @property
    def aligned(self) -> np.ndarray:
        """Per step, ``st_status`` bit 2 (:attr:`Step.aligned`)."""
        return np.asarray((self.st_status & _ST_ALIGNED) != 0)

    @property
    def attitude_valid(self) -> np.ndarray:
        """Per step, ``st_status`` bit 7 (:attr:`Step.attitude_valid`)."""
        return np.asarray((self.st_status & _ST_VALID) != 0)

    @property
    def converged(self) -> np.ndarray:
        """Per step, ``flags`` bit 2 (:attr:`Step.converged`)."""
        return np.asarray((self.flags & _FLAG_CONVERGED) != 0)

    def arrays(self) -> Dict[str, np.ndarray]:
        return {k: v for k, v in vars(self).items() if isinstance(v, np.ndarray)}

    def to_pandas(self) -> Any:
        """A ``pandas.DataFrame``, one column per scalar (``q0`` … ``q3``, ``rate_rad_s_x`` …;
        pandas is optional)."""
        return _pandas().DataFrame(_columns(self.arrays(), _WIDE))

    def __len__(self) -> int:
        return len(self.time_s)

    def __repr__(self) -> str:
        t = f"{self.time_s[0]:.3f}…{self.time_s[-1]:.3f} s" if len(self) else "empty"
        return f"Run(steps={len(self)}, time_s={t}, aligned at end={bool(self.aligned[-1]) if len(self) else None}, events={len(self.events)})"

    def _repr_html_(self) -> str:
        return f"<code>{_html.escape(repr(self))}</code>"


class _Unit:
    """What both units share: the step."""

    _native: Any

    def step(
        self,
        fog_dtheta_rad: Any,
        star: Optional[Tuple[float, Any]] = None,
        temperature_degc: Optional[Any] = None,
        star_valid: bool = True,
    ) -> Step:
        """One step: the four FOGs' raw increments over the step, rad (NaN: the sample does
        not arrive); ``star`` = ``(tag_t_s, q)``, a star-tracker solution arriving in this
        step (q the tracker's frame in the inertial frame, scalar first, a unit quaternion;
        ``tag_t_s`` the instant it holds, in unit time: step n ends at n × 5 ms)."""
        st = None if star is None else _star(star)
        return Step(**self._native.step((_f64(fog_dtheta_rad), st, _f64(temperature_degc), bool(star_valid))))


def _f64(v: Any) -> Any:
    """``v`` as a float64 array when it is numeric (ints, bools, floats), else as it is, for
    the native side to refuse with the argument's name and the shape it needs."""
    if v is None or isinstance(v, (str, bytes)):
        return v
    try:
        a = np.asarray(v)
    except Exception:
        return v
    return np.ascontiguousarray(a, dtype=np.float64) if a.dtype.kind in "biuf" else v


def _star(star: Any) -> Any:
    if isinstance(star, tuple) and len(star) == 2:
        return (star[0], _f64(star[1]))
    return star


class FlightCore(_Unit):
    """The spacecraft unit's flight core (four FOGs, star tracker, 5-ms steps), in-process.

    Each :meth:`step` encodes the FOG increments and the star-tracker solution into their
    frames on mock links and runs ``FlightCore::step``, as the simulator and the replay do.
    """

    _native: _ssis.FlightCore

    def __init__(self, table: Optional[Table] = None) -> None:
        self._native = _ssis.FlightCore(table)

    @property
    def dt_s(self) -> float:
        """Step period, s (0.005)."""
        return self._native.dt_s

    @property
    def steps(self) -> int:
        return self._native.steps

    def align(self, q: Any) -> None:
        """Sets the attitude to ``q`` (Λ, scalar first, a unit quaternion) and marks it
        aligned."""
        self._native.align(_f64(q))

    def counters(self) -> Dict[str, int]:
        """The unit's counters by name."""
        return dict(self._native.counters())

    def run(
        self,
        fog_dtheta_rad: Any,
        star_t_s: Optional[Any] = None,
        star_q: Optional[Any] = None,
        temperature_degc: Optional[Any] = None,
        star_valid: Optional[Any] = None,
    ) -> Run:
        """N steps from arrays, stepped in Rust (what N calls of :meth:`step` give, bit for
        bit): ``fog_dtheta_rad`` (N, 4) rad (NaN: the sample does not arrive); ``star_t_s``
        (N,) the tag of a star-tracker solution arriving in step k (NaN: none) and ``star_q``
        (N, 4) its quaternion; optional ``temperature_degc`` (N, 4) and ``star_valid`` (N,).
        Every row is checked before the first step."""
        d = self._native.run(_f64(fog_dtheta_rad), _f64(star_t_s), _f64(star_q), _f64(temperature_degc), _f64(star_valid))
        return Run(**d)

    def __copy__(self) -> "FlightCore":
        c = FlightCore.__new__(FlightCore)
        c._native = _copy.copy(self._native)
        return c

    def __deepcopy__(self, memo: Dict[int, Any]) -> "FlightCore":
        return self.__copy__()

    def __repr__(self) -> str:
        return repr(self._native)

    def _repr_html_(self) -> str:
        return f"<code>{_html.escape(repr(self))}</code>"


class QemuUnit(_Unit):
    """The spacecraft firmware (``ssis-fw-test``) in QEMU, in lockstep, stepped like
    :class:`FlightCore` (the runner's driver, ``ssis-qemu``'s: each step's frames on the
    emulated UARTs, a STEP control frame, the output frame back). The runner compares every
    output frame with the same core run in-process; :meth:`close` returns its report.
    Needs ``qemu-system-arm`` and the thumb toolchain (the firmware is built if out of
    date). ``events`` are the firmware's (its event frames); ``counters_moved`` is always
    empty here (the output frame pages one counter at a time)."""

    _native: _ssis.QemuUnit

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


@dataclass(repr=False)
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
    summary: Dict[str, Any]
    """What ``ssis-sim replay --json`` prints under ``replay``."""
    conventions: Dict[str, Any]
    """What it prints under ``conventions``."""
    report: str
    """The text report the command prints."""

    def arrays(self) -> Dict[str, np.ndarray]:
        """The per-output series by name."""
        return {k: v for k, v in vars(self).items() if isinstance(v, np.ndarray)}

    def to_pandas(self) -> Any:
        """The per-output series as a ``pandas.DataFrame``, one column per scalar: ``t_s``,
        ``q0`` … ``q3``, ``rate_rad_s_x`` … ``att_err_arcsec_z``, ``flags`` (pandas is
        optional)."""
        return _pandas().DataFrame(_columns(self.arrays(), _WIDE))

    def __repr__(self) -> str:
        acc = self.summary.get("accuracy", {}) if isinstance(self.summary, dict) else {}
        three = acc.get("attitude_error_3sigma_arcsec")
        span = f"{self.t_s[0]:.3f}…{self.t_s[-1]:.3f} s" if len(self.t_s) else "no arrays kept"
        return f"Replay(outputs={len(self.t_s)}, t_s={span}, steps={self.summary.get('steps')}, attitude 3σ={three} arcsec)"

    def _repr_html_(self) -> str:
        rows = "".join(f"<tr><td>{_html.escape(str(k))}</td><td>{_html.escape(str(v))}</td></tr>" for k, v in self.summary.items() if not isinstance(v, (dict, list)))
        return f"<b>ssis.Replay</b> <code>{_html.escape(repr(self))}</code><table>{rows}</table>"


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
