"""The model lab (``ssis-lab``) from Python: compare the FOG error model with a session,
diagnose what it lacks, add it, watch the held-out error fall, export the table.

A session argument is a path (streamed, as the command line reads it) or a
:class:`Session`. Results are the values ``ssis-lab … --json`` prints, as dicts, with the
diagnosis's candidates also as :class:`Candidate` objects.
"""

from __future__ import annotations

import html
import json
import os
from dataclasses import dataclass
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np

from . import _f64, _pandas, _ssis
from ._ssis import Table

__all__ = ["Session", "Model", "Candidate", "Diagnosis", "compare", "diagnose", "add", "fit", "held_out", "export", "report", "simulate"]


class Session:
    """A ground-test session (docs/SESSION-FORMAT.md) in memory."""

    def __init__(self, native: _ssis.Session) -> None:
        self._s = native

    @staticmethod
    def read(path: "os.PathLike[str] | str") -> "Session":
        """Reads and checks a session file (errors name the file, line and column)."""
        return Session(_ssis.Session.read(os.fspath(path)))

    @staticmethod
    def from_arrays(columns: "dict[str, Any]", name: str = "(arrays)") -> "Session":
        """A session from named columns (``t_s``, ``fog0_rate_rad_s``, …, as in a file)."""
        if not isinstance(columns, dict):
            raise _ssis.SsisError(f"columns: expected a dict of column name to 1-D array, got a `{type(columns).__name__}`")
        names = [str(k) for k in columns]
        cols = [_f64(columns[k]) for k in columns]
        return Session(_ssis.Session.from_arrays(names, cols, name))

    @property
    def names(self) -> List[str]:
        return self._s.names

    @property
    def file(self) -> str:
        return self._s.file

    @property
    def median_dt_s(self) -> float:
        return self._s.median_dt_s

    def __len__(self) -> int:
        return len(self._s)

    def __getitem__(self, name: str) -> np.ndarray:
        return self._s.column(name)

    def to_csv(self) -> str:
        return self._s.to_csv()

    def to_pandas(self) -> Any:
        """The columns as a ``pandas.DataFrame`` (pandas is optional)."""
        return _pandas().DataFrame({n: self[n] for n in self.names})

    def __repr__(self) -> str:
        return repr(self._s)

    def _repr_html_(self) -> str:
        return f"<code>{html.escape(repr(self))}</code>"


class Model:
    """The FOG error model (``ssis-error-model/1``)."""

    def __init__(self, native: _ssis.Model) -> None:
        self._m = native

    @staticmethod
    def init(terms: Sequence[str] = ("bias", "scale_factor", "misalignment"), t_ref_degc: float = 25.0, g_window_s: float = 0.0) -> "Model":
        """Version 1 with these terms and no coefficients (``ssis-lab init``)."""
        return Model(_ssis.Model.init(list(terms), t_ref_degc, g_window_s))

    @staticmethod
    def read(path: "os.PathLike[str] | str") -> "Model":
        return Model(_ssis.Model.read(os.fspath(path)))

    def write(self, path: "os.PathLike[str] | str") -> None:
        """Writes the model (an existing file is refused: the lab never overwrites a model)."""
        self._m.write(os.fspath(path))

    def to_toml(self) -> str:
        return self._m.to_toml()

    @property
    def version(self) -> int:
        return self._m.version

    @property
    def terms(self) -> List[str]:
        return self._m.terms

    @property
    def fitted(self) -> bool:
        """Whether the model has coefficients (fitted, or written in its file)."""
        return self._m.fitted

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Model) and self._m == other._m

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"Model(version={self.version}, terms={self.terms}, fitted={self.fitted})"

    def _repr_html_(self) -> str:
        return f"<code>{html.escape(repr(self))}</code>"


@dataclass
class Candidate:
    """One candidate missing effect, tested on held-out blocks."""

    name: str
    p: float
    """The F-test's p-value."""
    removed_deg_h: float
    """Systematic part of the held-out RMS the term removes, °/h."""
    significant: bool
    """Significant under the Benjamini–Hochberg FDR level."""


@dataclass
class Diagnosis:
    candidates: List[Candidate]
    most_significant: Optional[str]
    json: Dict[str, Any]
    """What ``ssis-lab diagnose --json`` prints under ``diagnosis``."""

    def to_pandas(self) -> Any:
        """One row per candidate: ``name``, ``p``, ``removed_deg_h``, ``significant``
        (pandas is optional)."""
        return _pandas().DataFrame([vars(c) for c in self.candidates], columns=["name", "p", "removed_deg_h", "significant"])


def _json(text: str) -> Dict[str, Any]:
    v: Dict[str, Any] = json.loads(text)
    return v


def _src(session: Any) -> Any:
    if isinstance(session, Session):
        return session._s
    if isinstance(session, (str, os.PathLike)):
        return os.fspath(session)
    raise _ssis.SsisError(f"session: expected a path or an ssis.lab.Session, got a `{type(session).__name__}`")


def compare(model: Model, session: Any, evaluate: bool = False, blocks: int = 10, progress: bool = False) -> Dict[str, Any]:
    """``ssis-lab compare``: the model fitted (or evaluated) on the session, per FOG.
    ``progress``: the command line's bar over the file's bytes on standard error."""
    return _json(_ssis.compare_json(model._m, _src(session), evaluate, blocks, progress))


def diagnose(model: Model, session: Any, level: float = 0.01, blocks: int = 10, progress: bool = False) -> Diagnosis:
    """``ssis-lab diagnose``: candidate terms ranked by their held-out F-test."""
    v = json.loads(_ssis.diagnose_json(model._m, _src(session), level, blocks, progress))
    c = [Candidate(x["candidate"], x["p_value"], x["removed_deg_h"], x["significant"]) for x in v["candidates"]]
    return Diagnosis(c, v["most_significant"], v)


def add(model: Model, term: str, session: Any, blocks: int = 10) -> Tuple[Model, Dict[str, Any]]:
    """``ssis-lab add``: the next version with ``term``, and its held-out gain (before/after
    per FOG). The new model is returned, not written."""
    m, v = _ssis.add_json(model._m, term, _src(session), blocks)
    return Model(m), _json(v)


def fit(model: Model, session: Any) -> Model:
    """The model with every term fitted on every row of the session: what :func:`compare`
    reports, as a model (``compare`` leaves ``model`` as it is). Export it with
    :func:`export` or write it."""
    return Model(_ssis.fit(model._m, _src(session)))


def held_out(models: Sequence[Model], session: Any, blocks: int = 10) -> List[Tuple[float, List[float]]]:
    """Held-out RMS, °/h, pooled and per FOG, of each model on the session (the history)."""
    return _ssis.held_out_deg_h([m._m for m in models], _src(session), blocks)


def export(model: Model, base: Optional[Table] = None, model_name: str = "(model)") -> Tuple[Table, Dict[str, Any], str]:
    """``ssis-lab export``: the calibration table from the model's onboard terms over ``base``
    (the nominal table by default), its revision + 1, with provenance; ``(table, json,
    text)``. Write it with ``table.write(path)``."""
    t, v, text = _ssis.export_json(model._m, base, model_name)
    return t, _json(v), text


def report(model: Model, session: Any, out: "os.PathLike[str] | str", versions: Optional[Sequence[Model]] = None, blocks: int = 10) -> None:
    """``ssis-lab report``: one HTML page of the fit, the diagnosis and the versions' history."""
    html = _ssis.report_html(model._m, _src(session), None if versions is None else [v._m for v in versions], blocks)
    path = os.fspath(out)
    if os.path.exists(path):
        raise _ssis.SsisError(f"{path}: exists; report writes a new file only")
    with open(path, "w", encoding="utf-8") as f:
        f.write(html)


def simulate(preset: str, out: "os.PathLike[str] | str", seed: int = 1, hidden: bool = True) -> float:
    """``ssis-lab simulate PRESET OUT``: a session with known effects; returns its white-noise
    floor, °/h."""
    return _ssis.simulate(preset, os.fspath(out), seed, hidden)
