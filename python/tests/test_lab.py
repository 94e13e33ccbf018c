"""ssis.lab against ``ssis-lab … --json``: the lab's loop on a simulated session with a
hidden effect, step by step through both."""

import os

import pytest

import ssis
from ssis import lab


@pytest.fixture()
def work(cli, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the tools and the package see the same relative names
    cli.run("ssis-lab", "simulate", "thermal", "th.csv")
    cli.run("ssis-lab", "init", "m.v1.toml")
    return tmp_path


def _drop(v, *keys):
    return {k: x for k, x in v.items() if k not in keys}


def test_the_loop_gives_the_command_lines_numbers(cli, work):
    m = lab.Model.init()
    assert m.to_toml() == (work / "m.v1.toml").read_text()
    assert lab.Model.read("m.v1.toml").to_toml() == m.to_toml()
    c = cli.json("ssis-lab", "compare", "--model", "m.v1.toml", "--session", "th.csv")["fit"]
    assert _drop(lab.compare(m, "th.csv", progress=True), "model") == _drop(c, "model")
    s = lab.Session.read("th.csv")
    assert _drop(lab.compare(m, s), "model") == _drop(c, "model")

    d = cli.json("ssis-lab", "diagnose", "--model", "m.v1.toml", "--session", "th.csv")["diagnosis"]
    got = lab.diagnose(m, "th.csv")
    assert got.json == d
    assert got.candidates[0].name == d["candidates"][0]["candidate"] == got.most_significant
    assert got.candidates[0].significant and got.candidates[0].p < 1e-6
    assert got.candidates[0].removed_deg_h == d["candidates"][0]["removed_deg_h"]

    term = got.most_significant
    a = cli.json("ssis-lab", "add", "--model", "m.v1.toml", "--session", "th.csv", term)
    m2, added = lab.add(m, term, "th.csv")
    assert _drop(added, "model") == _drop(a["added"], "model")
    assert m2.version == 2 and m2.to_toml() == (work / "m.v2.toml").read_text()
    assert added["pooled_after_deg_h"] < added["pooled_before_deg_h"]
    hist = lab.held_out([m, m2], "th.csv")
    assert [h["held_out_rms_deg_h"] for h in a["history"]] == [h[0] for h in hist]

    e = cli.json("ssis-lab", "export", "--model", "m.v2.toml", "--toml", "cli.toml")
    table, ex, text = lab.export(lab.Model.read("m.v2.toml"), model_name="m.v2.toml")
    assert ex == e["export"]
    table.write("py.toml")
    assert (work / "py.toml").read_text() == (work / "cli.toml").read_text()
    assert ssis.Table.read("cli.toml") == table

    cli.run("ssis-lab", "report", "--model", "m.v2.toml", "--session", "th.csv", "--out", "cli.html")
    lab.report(m2, "th.csv", "py.html", versions=[m, m2])
    assert (work / "py.html").read_text() == (work / "cli.html").read_text()


def test_session_errors_name_file_line_and_column(cli, work):
    text = (work / "th.csv").read_text().splitlines()
    text[5] = text[5].replace(",", ",x", 1)
    (work / "bad.csv").write_text("\n".join(text) + "\n")
    with pytest.raises(ssis.SsisError) as e:
        lab.Session.read("bad.csv")
    r = cli.run("ssis-lab", "compare", "--model", "m.v1.toml", "--session", "bad.csv", check=False)
    assert r.returncode != 0
    assert "bad.csv" in str(e.value) and "line 6" in str(e.value) and "column 2" in str(e.value)
    assert str(e.value) in r.stderr
    with pytest.raises(ssis.SsisError, match="line 6"):
        lab.compare(lab.Model.init(), "bad.csv")


def test_session_from_arrays_is_the_file(work):
    s = lab.Session.read("th.csv")
    t = lab.Session.from_arrays({n: s[n] for n in s.names}, name="th.csv")
    assert t.to_csv() == s.to_csv()
    m = lab.Model.init()
    assert lab.compare(m, t) == lab.compare(m, s)
    with pytest.raises(ssis.SsisError):
        lab.Session.from_arrays({"t_s": [0.0, 1.0], "nonsense_col": [1.0, 2.0]})


def test_models_are_never_overwritten(work):
    with pytest.raises(ssis.SsisError, match="never overwrites"):
        lab.Model.init().write("m.v1.toml")
    assert os.path.exists("m.v1.toml")
