"""The binding's boundary: bad input is refused with the argument's name and the shape it
needs, as an ``Exception`` (never a Rust panic, which Python raises as a
``BaseException``), and a seeded fuzz over the entry points finds no panic."""

import math
import os

import numpy as np
import pytest

import ssis
from ssis import lab

Q1 = [1.0, 0.0, 0.0, 0.0]


def _refused(fn, *names):
    """Calls ``fn``; it must raise an ``Exception`` whose message names one of ``names``."""
    with pytest.raises(Exception) as e:
        fn()
    msg = str(e.value)
    assert any(n in msg for n in names), f"{type(e.value).__name__}: {msg!r} names none of {names}"
    return msg


def _static(n=40):
    t = np.arange(1, n + 1) * 0.1
    cols = {"t_s": t}
    for i in range(4):
        cols[f"fog{i}_rad_s"] = np.full(n, 1e-6) + np.sin(np.arange(n)) * 1e-7
    for a in "xyz":
        cols[f"ref_{a}_rad_s"] = np.zeros(n)
    return cols


def test_session_columns_of_different_lengths_are_refused():
    cols = _static()
    cols["fog2_rad_s"] = cols["fog2_rad_s"][:5]
    msg = _refused(lambda: lab.Session.from_arrays(cols), "fog2_rad_s")
    assert "5 values" in msg
    cols = _static()
    cols["fog1_rad_s"] = np.zeros((40, 2))
    msg = _refused(lambda: lab.Session.from_arrays(cols), "fog1_rad_s")
    assert "shape (40, 2)" in msg
    _refused(lambda: lab.Session.from_arrays([1, 2]), "columns")
    _refused(lambda: lab.Session.from_arrays({"t_s": "abc"}), "t_s")


def test_steps_refuse_bad_shapes_tags_and_quaternions():
    core = ssis.FlightCore()
    msg = _refused(lambda: core.step(np.zeros((2, 4))), "fog_dtheta_rad")
    assert "shape (2, 4)" in msg
    _refused(lambda: core.step([0.0] * 3), "fog_dtheta_rad")
    _refused(lambda: core.step(np.zeros(4), star=([1, 0, 0, 0],)), "star")
    _refused(lambda: core.step(np.zeros(4), star=np.array(Q1)), "star")
    _refused(lambda: core.step(np.zeros(4), star=(0.1, [2, 0, 0, 0])), "star q")
    _refused(lambda: core.step(np.zeros(4), star=(math.nan, Q1)), "star")
    _refused(lambda: core.step(np.zeros(4), temperature_degc=[20.0, math.nan, 20, 20]), "temperature_degc")
    _refused(lambda: core.align([2, 0, 0, 0]), "q")
    # the native entry point itself, called with the wrong tuple: its length and the item named
    native = core._native
    msg = _refused(lambda: native.step((np.zeros(4), None, None)), "star_valid")
    assert "tuple of 4" in msg and "of 3 items" in msg, msg
    msg = _refused(lambda: native.step((np.zeros(4), None, None, "yes")), "star_valid")
    assert "a `str`" in msg, msg
    _refused(lambda: core.align([math.nan, 0, 0, 0]), "q")
    assert core.steps == 0, "a refused step is not taken"
    core.align(Q1)
    core.step(np.zeros(4), star=(0.0, Q1))
    _refused(lambda: core.run(np.zeros((10, 3))), "fog_dtheta_rad")
    _refused(lambda: core.run(np.zeros((10, 4)), np.zeros(10)), "star_t_s and star_q")
    bad = np.tile(Q1, (10, 1))
    bad[7] = [0, 0, 0, 0]
    _refused(lambda: core.run(np.zeros((10, 4)), np.full(10, 0.5), bad), "star_q[7]")
    assert core.steps == 1, "a refused run takes no step"


def test_allan_refuses_nan_with_its_place():
    r = np.zeros(1000)
    r[10] = math.nan
    msg = _refused(lambda: ssis.cal.allan(r, 0.1), "rate_rad_s")
    assert "sample 10" in msg
    _refused(lambda: ssis.cal.allan(np.zeros((100, 2)), 0.1), "rate_rad_s")
    _refused(lambda: ssis.cal.allan(np.zeros(100), "x"), "dt_s")


def test_model_terms_are_checked_as_the_command_line_does():
    msg = _refused(lambda: lab.Model.init(["bias", "scalefactor"]), "scalefactor")
    assert "did you mean `scale_factor`" in msg


def test_compare_then_export_says_what_to_call_and_fit_works(tmp_path):
    p = tmp_path / "th.csv"
    lab.simulate("thermal", p, seed=3)
    m = lab.Model.init()
    lab.compare(m, p)
    msg = _refused(lambda: lab.export(m), "ssis.lab.fit")
    assert "compare" in msg
    f = lab.fit(m, p)
    assert f.fitted and not m.fitted
    table, v, _ = lab.export(f)
    assert v["applied_onboard"]


def test_table_refuses_an_unknown_format_and_bad_values(tmp_path):
    t = ssis.Table.default()
    _refused(lambda: t.write(tmp_path / "t.json"), "t.json")
    assert not (tmp_path / "t.json").exists()
    _refused(lambda: t.set("fog[0].bias_rad_s", math.nan), "value")
    _refused(lambda: ssis.Table.from_toml("format = 1"), "(text)")


# ------------------------------------------------------------------- fuzz

def _values(rng):
    """Random arguments: wrong shapes, dtypes, lengths, NaN, empty arrays, other types."""
    n = int(rng.integers(0, 7))
    choices = [
        lambda: rng.normal(size=n),
        lambda: rng.normal(size=4),
        lambda: rng.normal(size=(n, 4)),
        lambda: rng.normal(size=(4, n)),
        lambda: np.full(int(rng.integers(0, 6)), math.nan),
        lambda: np.array([], dtype=np.float64),
        lambda: rng.integers(-3, 3, size=4),
        lambda: rng.normal(size=4).astype(np.float32),
        lambda: np.array(["a", "b", "c", "d"]),
        lambda: [float(x) for x in rng.normal(size=n)],
        lambda: (float(rng.normal()), rng.normal(size=4)),
        lambda: (float(rng.normal()),),
        lambda: float(rng.choice([math.nan, math.inf, -1.0, 0.0, 1e300, 0.005])),
        lambda: int(rng.integers(-2, 5)),
        lambda: None,
        lambda: "x",
        lambda: {"t_s": rng.normal(size=n)},
        lambda: np.array(Q1) * float(rng.choice([1.0, 2.0, math.nan, 0.0])),
    ]
    return choices[int(rng.integers(len(choices)))]()


def _entry_points(rng, core, model, session):
    v = lambda: _values(rng)  # noqa: E731
    cols = lambda: {k: (v() if rng.random() < 0.3 else c) for k, c in _static(int(rng.integers(0, 50))).items()}  # noqa: E731
    return [
        lambda: core.step(v()),
        lambda: core.step(v(), star=v()),
        lambda: core.step(np.zeros(4), star=(v(), v()), temperature_degc=v()),
        lambda: core.align(v()),
        lambda: core.run(v(), v(), v()),
        lambda: core.run(rng.normal(size=(int(rng.integers(0, 4)), 4)) * 1e-6, v(), v(), v(), v()),
        lambda: ssis.cal.allan(v(), v()),
        lambda: ssis.cal.allan(rng.normal(size=int(rng.integers(0, 80))) * v() if rng.random() < 0.5 else rng.normal(size=40), 0.1),
        lambda: lab.Session.from_arrays(cols()),
        lambda: lab.Session.from_arrays(v()),
        lambda: lab.Model.init([str(v())]),
        lambda: lab.Model.init(["bias", "scalefactor", "misalign", "sinusoid:x"][: int(rng.integers(1, 5))]),
        lambda: ssis.Table.default().set(str(rng.choice(ssis.Table.fields())), v()),
        lambda: ssis.Table.default().get(str(v())),
        lambda: ssis.Table.from_toml(str(v())),
        lambda: ssis._ssis.Session.from_arrays([str(v())], [v()]),
        lambda: ssis._ssis.allan_json(v(), v()),
        lambda: ssis._ssis.FlightCore().__setstate__(bytes(rng.integers(0, 256, size=int(rng.integers(0, 64)), dtype=np.uint8))),
        lambda: ssis._ssis.Session().__setstate__(bytes(rng.integers(0, 256, size=int(rng.integers(0, 64)), dtype=np.uint8))),
        lambda: lab.export(model),
        lambda: ssis.cal.allan_session(session, fog=int(rng.integers(-1, 6))),
    ]


def test_fuzz_entry_points_never_panic():
    calls = int(os.environ.get("SSIS_FUZZ_CALLS", "100000"))
    rng = np.random.default_rng(39)
    core = ssis.FlightCore()
    model = lab.Model.init()
    session = lab.Session.from_arrays(_static(400))
    entries = _entry_points(rng, core, model, session)
    panics, refused, done = [], 0, 0
    for k in range(calls):
        i = int(rng.integers(len(entries)))
        try:
            entries[i]()
            done += 1
        except Exception:
            refused += 1
        except BaseException as e:  # a Rust panic (pyo3_runtime.PanicException)
            if isinstance(e, KeyboardInterrupt):
                raise
            panics.append((k, i, f"{type(e).__name__}: {e}"))
        if k % 2000 == 0:
            core = ssis.FlightCore()  # keep the core's steps cheap
            entries = _entry_points(rng, core, model, session)
    print(f"{calls} calls: {done} accepted, {refused} refused, {len(panics)} panics")
    assert not panics, panics[:5]
    assert refused > calls // 10 and done > calls // 20
