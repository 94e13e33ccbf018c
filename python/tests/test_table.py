"""ssis.Table against ``ssis-sim table``."""

import math

import pytest

import ssis


def test_default_is_the_command_lines(cli, tmp_path):
    p = tmp_path / "default.toml"
    cli.run("ssis-sim", "table", "new", p)
    t = ssis.Table.read(p)
    assert t == ssis.Table.default()
    assert ssis.Table.diff(t, ssis.Table.default())[0] == []
    assert t.crc == ssis.Table.default().crc


def test_fields_by_name_and_diff_as_the_command_line(cli, tmp_path, root):
    a = ssis.Table.read(root / "examples/basilisk/table.toml")
    b = ssis.Table.read(root / "examples/basilisk/table.toml")
    b.set("fog[2].bias_rad_s", 1e-6)
    b.set("observer.st_sigma_arcsec", 5.0)
    assert b.get("fog[2].bias_rad_s") == 1e-6
    pa, pb = tmp_path / "a.toml", tmp_path / "b.toml"
    a.write(pa)
    b.write(pb)
    changes, text = ssis.Table.diff(a, b)
    assert [c[0] for c in changes] == ["fog[2].bias_rad_s", "observer.st_sigma_arcsec"]
    assert changes[0][1:] == (0.0, 1e-6)
    p = cli.run("ssis-sim", "table", "diff", pa, pb, check=False)
    assert p.returncode == 1
    assert text in p.stdout
    # the binary form: the same bytes as the command line converts
    cli.run("ssis-sim", "table", "to-bin", pb, tmp_path / "cli.bin")
    b.write(tmp_path / "py.bin")
    assert (tmp_path / "cli.bin").read_bytes() == (tmp_path / "py.bin").read_bytes()
    assert ssis.Table.read(tmp_path / "cli.bin") == b


def test_every_field_reads_and_writes_by_name():
    t = ssis.Table.default()
    names = ssis.Table.fields()
    assert "fog[0].bias_rad_s" in names and "observer.arw_deg_sqrt_h" in names
    for n in names:
        v = t.get(n)
        assert math.isfinite(v)


def test_errors_name_file_line_and_field_as_the_command_line(cli, tmp_path, root):
    text = (root / "examples/basilisk/table.toml").read_text().replace("t_rate_filter_s = 30.0", "t_rate_filter_s = \"x\"")
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(ssis.SsisError) as e:
        ssis.Table.read(p)
    r = cli.run("ssis-sim", "table", "show", p, check=False)
    assert r.returncode != 0
    msg = str(e.value)
    assert str(p) in msg and "t_rate_filter_s" in msg and "line" in msg
    assert msg in r.stderr
    with pytest.raises(ssis.SsisError, match="not a field"):
        ssis.Table.default().get("fog[9].bias")
    with pytest.raises(ssis.SsisError, match="plausible range"):
        ssis.Table.default().set("observer.st_sigma_arcsec", 1e6)


def test_write_never_overwrites(tmp_path):
    p = tmp_path / "t.toml"
    ssis.Table.default().write(p)
    with pytest.raises(ssis.SsisError, match="exists"):
        ssis.Table.default().write(p)
    ssis.Table.default().write(p, force=True)
