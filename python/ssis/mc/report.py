"""The budget of a Monte Carlo campaign's results (docs/MONTE-CARLO.md, "The budget report").

Per error index and axis (each ``index.*`` column: one value per run), the value at the
three probability levels of ECSS-E-ST-60-10C (68.3, 95.4, 99.73 %) as order statistics
with their distribution-free confidence intervals; histograms and empirical CDFs; the
worst runs with their drawn parameters and the command that replays each; and the
Spearman rank correlation of every dispersed parameter with every index, naming the
drivers.

**Order statistics.** With n runs sorted x(1) ≤ … ≤ x(n), the p-quantile ξ is estimated by
x(⌈np⌉). The number B of runs at or below ξ is binomial (n, p), so P(x(j) ≤ ξ) = P(B ≥ j)
whatever the distribution: the interval [x(l), x(u)] holds ξ with probability
P(l ≤ B < u), and x(u) is a one-sided upper bound at confidence P(B < u). The report gives
the two-sided 95 % interval and the one-sided 95 % upper bound; an upper bound on the
99.73 % value exists only with n ≥ 1,109 runs (then it is the largest run: 1 − 0.9973ⁿ ≥
0.95), and the k-th largest run bounds it once n is large enough for k (e.g. the 4th
largest with 2,870 runs; with 10,000 runs, the 19th largest).
"""

from __future__ import annotations

import html
import math
import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from . import INDEX, PARAM, load

__all__ = ["LEVELS", "CONFIDENCE", "Quantile", "quantile", "runs_needed", "binom_cdf", "budget", "sensitivity",
           "chance_rho", "drivers", "worst", "Report", "report"]

LEVELS = (0.683, 0.954, 0.9973)
"""The probability levels of the budget (ECSS-E-ST-60-10C: 1σ, 2σ, 3σ of a normal law)."""
CONFIDENCE = 0.95
"""The confidence of the intervals and bounds."""


def binom_cdf(n: int, p: float) -> np.ndarray:
    """F[k] = P(B ≤ k) for B ~ binomial(n, p), k = 0 … n (log-space pmf, summed)."""
    k = np.arange(n + 1, dtype=float)
    lg = np.vectorize(math.lgamma)
    logpmf = lg(n + 1.0) - lg(k + 1.0) - lg(n - k + 1.0) + k * math.log(p) + (n - k) * math.log1p(-p)
    return np.minimum(np.cumsum(np.exp(logpmf)), 1.0)


def runs_needed(p: float, confidence: float = CONFIDENCE, k: int = 1) -> int:
    """The fewest runs whose k-th largest value is an upper bound on the p-quantile at
    ``confidence`` (k = 1: the largest; 1 − pⁿ ≥ confidence)."""
    if k == 1:
        return math.ceil(math.log(1 - confidence) / math.log(p))
    n = runs_needed(p, confidence, 1)
    while binom_cdf(n, p)[n - k] < confidence:
        n += 1
    return n


@dataclass(frozen=True)
class Quantile:
    """The p-quantile of n values with its order-statistic bounds (1-based ranks)."""

    p: float
    n: int
    value: float
    rank: int
    lo: Optional[float]
    """Lower end of the two-sided interval (None: too few runs)."""
    hi: Optional[float]
    """Upper end of the two-sided interval (None: too few runs)."""
    upper: Optional[float]
    """One-sided upper bound at :data:`CONFIDENCE` (None: too few runs)."""
    upper_rank: Optional[int]


def quantile(values: Sequence[float], p: float, confidence: float = CONFIDENCE) -> Quantile:
    x = np.sort(np.asarray(values, dtype=float))
    n = len(x)
    if n == 0:
        raise ValueError("no runs")
    F = binom_cdf(n, p)  # F[j-1] = P(B < j) = P(x(j) > ξ)
    rank = max(1, math.ceil(n * p))
    a = (1 - confidence) / 2
    lows = [j for j in range(1, n + 1) if F[j - 1] <= a]
    highs = [j for j in range(1, n + 1) if F[j - 1] >= 1 - a]
    ups = [j for j in range(1, n + 1) if F[j - 1] >= confidence]
    lo = x[lows[-1] - 1] if lows else None
    hi = x[highs[0] - 1] if highs else None
    up_rank = ups[0] if ups else None
    return Quantile(p, n, float(x[rank - 1]), rank, None if lo is None else float(lo),
                    None if hi is None else float(hi), None if up_rank is None else float(x[up_rank - 1]), up_rank)


def _index_columns(df: Any) -> List[str]:
    return [c for c in df.columns if c.startswith(INDEX)]


def _param_columns(df: Any) -> List[str]:
    """The dispersed parameters: numeric ``param.*`` columns that vary over the runs."""
    out = []
    for c in df.columns:
        if c.startswith(PARAM):
            s = df[c]
            if (s.dtype.kind in "fiub") and s.nunique(dropna=True) > 1:
                out.append(c)
    return out


def budget(df: Any) -> Any:
    """One row per index column: n, and per level the value, its 95 % interval and upper bound."""
    import pandas as pd  # type: ignore[import-untyped,unused-ignore]

    rows = []
    for col in _index_columns(df):
        v = df[col].to_numpy(dtype=float)
        v = v[np.isfinite(v)]
        row: Dict[str, Any] = {"index": col[len(INDEX):], "n": len(v)}
        for p in LEVELS:
            q = quantile(v, p)
            tag = f"{p * 100:g}%"
            row[tag] = q.value
            row[f"{tag} lo"] = q.lo
            row[f"{tag} hi"] = q.hi
            row[f"{tag} upper"] = q.upper
        row["max"] = float(v.max()) if len(v) else math.nan
        rows.append(row)
    return pd.DataFrame(rows)


def sensitivity(df: Any) -> Any:
    """Spearman rank correlation of each dispersed parameter (rows) with each index
    (columns). A parameter of both signs enters twice: its drawn value δ (a monotonic
    effect: a larger scale factor, a larger error) and its magnitude ``|name|`` (a
    zero-mean dispersion whose either sign hurts, as a bias's does, correlates with the
    index only through its size). A parameter defined in fewer than half the runs (a
    fault's time or FOG, NaN when it does not occur) gets no ρ (its ``.occurs`` has one)."""
    import pandas as pd  # type: ignore[import-untyped,unused-ignore]

    params, idx = _param_columns(df), _index_columns(df)
    cols = {c[len(PARAM):]: df[c].astype(float) for c in params}
    for c in params:
        v = df[c].astype(float)
        if (v < 0).any() and (v > 0).any():
            cols[f"|{c[len(PARAM):]}|"] = v.abs()
    frame = pd.DataFrame({**cols, **{c[len(INDEX):]: df[c].astype(float) for c in idx}})
    names = list(cols)
    least = max(3, len(df) // 2)
    corr = frame.rank(method="average").corr(method="pearson", min_periods=least)
    return corr.loc[names, [c[len(INDEX):] for c in idx]]


def chance_rho(n: int) -> float:
    """The |ρ| that n runs of independent parameter and index exceed with probability 5 %
    (two-sided): about 1.96/√(n − 1), the normal approximation of Spearman's ρ under
    independence. A driver below it is not told apart from no driver at all."""
    return 1.96 / math.sqrt(max(n - 1, 1))


def drivers(corr: Any, top: int = 3) -> Dict[str, List[Tuple[str, float]]]:
    """Per index, its ``top`` parameters by |ρ| (largest first; a parameter and its
    magnitude count once, by the larger)."""
    out = {}
    for col in corr.columns:
        s = corr[col].dropna()
        picked: List[Tuple[str, float]] = []
        seen = set()
        for k in s.abs().sort_values(ascending=False, kind="stable").index:
            base = str(k).strip("|")
            if base in seen:
                continue
            seen.add(base)
            picked.append((str(k), float(s[k])))
            if len(picked) == top:
                break
        out[col] = picked
    return out


def worst(df: Any, col: str, k: int = 3) -> Any:
    """The ``k`` runs with the largest value of index column ``col``."""
    return df.sort_values([col, "run"], ascending=[False, True], kind="stable").head(k)


def _fmt(x: Optional[float]) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "—"
    a = abs(x)
    return f"{x:.3g}" if a < 0.01 or a >= 1e4 else f"{x:.4g}" if a < 100 else f"{x:.1f}"


@dataclass
class Report:
    """The budget of a results folder; :meth:`text` and :meth:`html` render it."""

    df: Any
    budget: Any
    sensitivity: Any
    campaign_path: str
    title: str

    def text(self) -> str:
        lines = [f"{self.title}: {len(self.df)} runs; index values in arcsec at each level "
                 f"[{CONFIDENCE * 100:g} % order-statistic interval]"]
        hdr = f"{'index':<20}" + "".join(f"{f'{p * 100:g} %':>30}" for p in LEVELS)
        lines.append(hdr)
        for _, r in self.budget.iterrows():
            cells = ""
            for p in LEVELS:
                t = f"{p * 100:g}%"
                cells += f"{_fmt(r[t]) + ' [' + _fmt(r[t + ' lo']) + ', ' + _fmt(r[t + ' hi']) + ']':>30}"
            lines.append(f"{r['index']:<20}{cells}")
        n = len(self.df)
        need = runs_needed(LEVELS[-1])
        if n < need:
            lines.append(f"(a 95 % upper bound on the 99.73 % value needs ≥ {need} runs; this campaign has {n})")
        if len(self.sensitivity.index):
            floor = chance_rho(n)
            lines.append(f"drivers (Spearman ρ, largest |ρ| first; |ρ| < {floor:.2f} is within chance "
                         f"at 95 % over {n} runs, marked ~):")
            for k, v in drivers(self.sensitivity).items():
                lines.append(f"  {k:<18} " + ", ".join(f"{p} {r:+.2f}{'' if abs(r) >= floor else '~'}"
                                                       for p, r in v))
        return "\n".join(lines)

    def html(self) -> str:
        return _html_page(self)


def report(out: Union[str, Path], campaign_path: Optional[str] = None) -> Report:
    """The budget of the results under ``out/`` (``campaign_path``: the name the replay
    commands give the campaign file; default ``out/campaign.toml``)."""
    df = load(out)
    cp = campaign_path or str(Path(out) / "campaign.toml")
    return Report(df, budget(df), sensitivity(df), cp, f"Pointing budget of {Path(out).name or out}")


# ---------------------------------------------------------------------------------------
# HTML: one self-contained page, inline SVG, no script, no external reference.

_CSS = """
body{font-family:system-ui,sans-serif;margin:1.5em;color:#222;max-width:1200px}
table{border-collapse:collapse;margin:0.5em 0 1.5em}
td,th{border:1px solid #ccc;padding:2px 6px;text-align:right;font-size:13px}
th{background:#f2f2f2}td.l,th.l{text-align:left}
code{font-size:12px}
.fig{display:inline-block;margin:4px}
small{color:#555}
"""


def _svg_hist_cdf(v: np.ndarray, title: str, marks: Sequence[Tuple[float, float]]) -> str:
    """A histogram (bars) and the empirical CDF (line, right scale) of ``v``, with the
    level marks (p, value) as vertical lines."""
    W, H, L, R, T, B = 360, 200, 44, 36, 22, 30
    pw, ph = W - L - R, H - T - B
    v = np.sort(v[np.isfinite(v)])
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" viewBox="0 0 {W} {H}">',
             f'<text x="{W / 2}" y="14" text-anchor="middle" font-size="12">{html.escape(title)}</text>']
    if len(v) == 0:
        return "".join(parts) + "</svg>"
    lo, hi = float(v[0]), float(v[-1])
    if hi <= lo:
        hi = lo + (abs(lo) if lo else 1.0) * 1e-6 + 1e-12
    counts, edges = np.histogram(v, bins=min(40, max(5, int(math.sqrt(len(v))))), range=(lo, hi))
    cmax = max(1, int(counts.max()))

    def X(x: float) -> float:
        return L + (x - lo) / (hi - lo) * pw

    for c, a, b in zip(counts, edges[:-1], edges[1:]):
        h = c / cmax * ph
        parts.append(f'<rect x="{X(a):.1f}" y="{T + ph - h:.1f}" width="{max(0.5, X(b) - X(a) - 0.5):.1f}" '
                     f'height="{h:.1f}" fill="#9cc3e6"/>')
    n = len(v)
    # the decimated CDF steps: rank j·stride
    stride = max(1, n // 400)
    pts = " ".join(f"{X(float(v[j])):.1f},{T + ph - (j + 1) / n * ph:.1f}" for j in range(0, n, stride))
    pts += f" {X(float(v[-1])):.1f},{T:.1f}"
    parts.append(f'<polyline points="{pts}" fill="none" stroke="#c0392b" stroke-width="1.5"/>')
    for p, x in marks:
        parts.append(f'<line x1="{X(x):.1f}" y1="{T}" x2="{X(x):.1f}" y2="{T + ph}" stroke="#333" '
                     f'stroke-dasharray="3,2"/><text x="{X(x) + 2:.1f}" y="{T + 10 + 10 * LEVELS.index(p)}" '
                     f'font-size="9">{p * 100:g}%</text>')
    parts.append(f'<rect x="{L}" y="{T}" width="{pw}" height="{ph}" fill="none" stroke="#888"/>')
    parts.append(f'<text x="{L}" y="{H - 12}" font-size="10" text-anchor="middle">{_fmt(lo)}</text>'
                 f'<text x="{L + pw}" y="{H - 12}" font-size="10" text-anchor="middle">{_fmt(hi)}</text>'
                 f'<text x="{L + pw / 2}" y="{H - 2}" font-size="10" text-anchor="middle">arcsec</text>'
                 f'<text x="{L - 4}" y="{T + 8}" font-size="10" text-anchor="end">{cmax}</text>'
                 f'<text x="{L - 4}" y="{T + ph}" font-size="10" text-anchor="end">0</text>'
                 f'<text x="{L + pw + 4}" y="{T + 8}" font-size="10" fill="#c0392b">1</text>'
                 f'<text x="{L + pw + 4}" y="{T + ph}" font-size="10" fill="#c0392b">0</text>')
    return "".join(parts) + "</svg>"


def _html_page(r: Report) -> str:
    e = html.escape
    df, n = r.df, len(r.df)
    need = runs_needed(LEVELS[-1])
    out = ["<!DOCTYPE html><html><head><meta charset=\"utf-8\">", f"<title>{e(r.title)}</title>",
           f"<style>{_CSS}</style></head><body>", f"<h1>{e(r.title)}</h1>",
           f"<p>{n} runs; every index in arcsec. Each level's value is the order statistic x(⌈np⌉) of the "
           f"{n} runs, with its two-sided {CONFIDENCE * 100:g} % interval and one-sided {CONFIDENCE * 100:g} % upper "
           f"bound (distribution-free, binomial). A {CONFIDENCE * 100:g} % upper bound on the 99.73 % value needs "
           f"at least {need} runs (then the largest run is it)"
           + ("." if n >= need else f": this campaign has {n}, so that bound is “—”.") + "</p>"]
    out.append("<h2>Budget</h2><table><tr><th class=l>index</th><th>n</th>")
    for p in LEVELS:
        out.append(f"<th>{p * 100:g} %</th><th>{CONFIDENCE * 100:g} % interval</th><th>upper bound</th>")
    out.append("<th>max</th></tr>")
    for _, b in r.budget.iterrows():
        out.append(f"<tr><td class=l>{e(b['index'])}</td><td>{b['n']}</td>")
        for p in LEVELS:
            t = f"{p * 100:g}%"
            out.append(f"<td><b>{_fmt(b[t])}</b></td><td>[{_fmt(b[t + ' lo'])}, {_fmt(b[t + ' hi'])}]</td>"
                       f"<td>{_fmt(b[t + ' upper'])}</td>")
        out.append(f"<td>{_fmt(b['max'])}</td></tr>")
    out.append("</table>")
    out.append("<h2>Distributions</h2><p><small>Histogram (bars, left scale: runs per bin) and empirical CDF "
               "(red, right scale) of each index over the runs; dashed: the three levels.</small></p>")
    for _, b in r.budget.iterrows():
        v = df[INDEX + b["index"]].to_numpy(dtype=float)
        marks = [(p, float(b[f"{p * 100:g}%"])) for p in LEVELS]
        out.append(f'<div class="fig">{_svg_hist_cdf(v, b["index"], marks)}</div>')
    out.append("<h2>Drivers</h2>")
    corr = r.sensitivity
    if len(corr.index) == 0:
        out.append("<p>No parameter varies over the runs: nothing to rank.</p>")
    else:
        out.append("<p><small>Spearman rank correlation ρ of each dispersed parameter with each index over the "
                   f"{n} runs (|ρ| above {chance_rho(n):.2f} is beyond chance at 95 %). "
                   "The drivers of an index are its parameters of largest |ρ|; <code>|name|</code> is the size of a "
                   "parameter's offset, the driver of an index when either sign of it hurts.</small></p>")
        out.append("<table><tr><th class=l>index</th><th class=l>drivers (ρ)</th></tr>")
        for k, v in drivers(corr).items():
            out.append(f"<tr><td class=l>{e(k)}</td><td class=l>"
                       + ", ".join(f"<b>{e(p)}</b> {rho:+.2f}" for p, rho in v) + "</td></tr>")
        out.append("</table><table><tr><th class=l>parameter</th>"
                   + "".join(f"<th>{e(c)}</th>" for c in corr.columns) + "</tr>")
        for p, row in corr.iterrows():
            out.append(f"<tr><td class=l>{e(str(p))}</td>" + "".join(f"<td>{float(x):+.2f}</td>" for x in row) + "</tr>")
        out.append("</table>")
    out.append("<h2>Worst runs</h2><p><small>Per index, the run of the largest value, its drawn parameters and "
               "the command that replays exactly that run.</small></p>")
    out.append("<table><tr><th class=l>index</th><th>value</th><th>run</th><th class=l>replay</th>"
               "<th class=l>parameters</th></tr>")
    pcols = [c for c in df.columns if c.startswith(PARAM)]
    for _, b in r.budget.iterrows():
        w = worst(df, INDEX + b["index"], 1)
        for _, row in w.iterrows():
            params = ", ".join(f"{c[len(PARAM):]}={_fmt(row[c]) if isinstance(row[c], float) else row[c]}"
                               for c in pcols)
            cmd = f"ssis-mc replay {shlex.quote(r.campaign_path)} --run {int(row['run'])}"
            out.append(f"<tr><td class=l>{e(b['index'])}</td><td>{_fmt(float(row[INDEX + b['index']]))}</td>"
                       f"<td>{int(row['run'])}</td><td class=l><code>{e(cmd)}</code></td>"
                       f"<td class=l><small>{e(params)}</small></td></tr>")
    out.append("</table></body></html>\n")
    return "".join(out)
