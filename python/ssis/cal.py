"""The calibration methods of ``ssis-cal`` on arrays or sessions (the numbers of
``ssis-cal … --json``)."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from typing import Any, Dict, Optional, Union

import numpy as np

from . import _f64, _pandas, _ssis
from ._ssis import Table

__all__ = ["Allan", "allan", "allan_session", "turns", "sins", "thermal", "magnetic", "orbital"]


@dataclass(repr=False)
class Allan:
    """An overlapping Allan deviation and its noise terms (values with their 95 % intervals:
    ``{"value", "ci95_low", "ci95_high"}``, or ``{"upper_bound_95"}`` when the session does not
    resolve the term: the other terms explain every point of σ(τ) without it). B is read
    from the flicker floor of the fit, so a session that shows only white noise and a rate
    random walk gives B as a bound."""

    tau_s: np.ndarray
    adev_deg_h: np.ndarray
    ci95_low_deg_h: np.ndarray
    ci95_high_deg_h: np.ndarray
    arw_deg_sqrt_h: Dict[str, Any]
    bias_instability_deg_h: Dict[str, Any]
    bias_instability_tau_s: float
    rrw_deg_h_sqrt_h: Dict[str, Any]
    json: Dict[str, Any]
    """The whole value ``ssis-cal allan --json`` prints under ``allan``."""

    def to_pandas(self) -> Any:
        """One row per τ: ``tau_s``, ``adev_deg_h``, ``ci95_low_deg_h``, ``ci95_high_deg_h``
        (pandas is optional)."""
        return _pandas().DataFrame(
            {"tau_s": self.tau_s, "adev_deg_h": self.adev_deg_h, "ci95_low_deg_h": self.ci95_low_deg_h, "ci95_high_deg_h": self.ci95_high_deg_h}
        )

    def __repr__(self) -> str:
        def term(e: Dict[str, Any]) -> str:
            if "value" in e:
                return f"{e['value']:.4g} [{e['ci95_low']:.4g}, {e['ci95_high']:.4g}]"
            return f"≤ {e['upper_bound_95']:.4g}"

        return (
            f"Allan(points={len(self.tau_s)}, ARW={term(self.arw_deg_sqrt_h)} °/√h, "
            f"B={term(self.bias_instability_deg_h)} °/h, RRW={term(self.rrw_deg_h_sqrt_h)} °/h/√h)"
        )


def _allan(text: str) -> Allan:
    v: Dict[str, Any] = json.loads(text)

    def col(k: str) -> np.ndarray:
        return np.array([p[k] for p in v["points"]], dtype=np.float64)

    return Allan(
        tau_s=col("tau_s"),
        adev_deg_h=col("adev_deg_h"),
        ci95_low_deg_h=col("ci95_low_deg_h"),
        ci95_high_deg_h=col("ci95_high_deg_h"),
        arw_deg_sqrt_h=v["arw_deg_sqrt_h"],
        bias_instability_deg_h=v["bias_instability_deg_h"],
        bias_instability_tau_s=v["bias_instability_tau_s"],
        rrw_deg_h_sqrt_h=v["rrw_deg_h_sqrt_h"],
        json=v,
    )


def allan(rate_rad_s: Any, dt_s: float) -> Allan:
    """Overlapping Allan deviation (8 τ per decade) of a rate series sampled every ``dt_s``."""
    return _allan(_ssis.allan_json(_f64(rate_rad_s), dt_s))


def allan_session(session: Any, fog: int = 0) -> Allan:
    """``ssis-cal allan --session S --fog N``: a static session's FOG (a path or a
    :class:`ssis.lab.Session`)."""
    return _allan(_ssis.allan_session_json(_s(session), fog))


def turns(session: Any, table: Optional[Table] = None) -> Dict[str, Any]:
    """``ssis-cal turns``: misalignment from three calibration turns (γ from ``table``)."""
    return _json(_ssis.turns_json(_s(session), table))


def sins(session: Any, table: Optional[Table] = None) -> Dict[str, Any]:
    """``ssis-cal sins``: the triad's angles from SINS reversals (started from ``table``)."""
    return _json(_ssis.sins_json(_s(session), table))


def thermal(session: Any, fog: int = 0) -> Dict[str, Any]:
    """``ssis-cal thermal --session S --fog N``: the T × G ANOVA of a chamber session (Table
    1's levels) and the thermal model when it is worth building."""
    return _json(_ssis.thermal_json(_s(session), fog))


def magnetic(unscreened: Any, screened: Any) -> Dict[str, Any]:
    """``ssis-cal magnetic``: eqs. (1)-(3) from an unscreened and a screened session (the
    field from the sessions' columns)."""
    return _json(_ssis.magnetic_json(_s(unscreened), _s(screened)))


def _json(text: str) -> Dict[str, Any]:
    v: Dict[str, Any] = json.loads(text)
    return v


def _s(session: Any) -> Union[str, Any]:
    from .lab import Session

    if isinstance(session, Session):
        return session._s
    return str(session)


def orbital(output: Any, star: Any, table: Table) -> Dict[str, Any]:
    """``ssis-cal orbital --output O --star S --table T``: the orbital calibration of a
    flight's telemetry (docs/TUTORIAL-CALIBRATION.md section 6): zero bias from the
    observer's steady drift estimate, scale factors from the 360° maneuvers, the
    star-tracker mount by RLS. ``output`` and ``star`` are the output-link and
    star-tracker-link captures (paths), ``table`` the table the unit flew. Returns the
    command line's ``orbital`` JSON value, with ``"table"``: the table flown with the fields
    found set, as the command line writes it (``table`` itself is left as it is)."""
    text, updated = _ssis.orbital_json(os.fspath(output), os.fspath(star), table)
    v: Dict[str, Any] = json.loads(text)
    v["table"] = updated
    return v
