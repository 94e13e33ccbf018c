"""Fixtures: the command-line tools the package is compared with, the test campaign of
the Monte Carlo tests.

The tools are the host workspace's release binaries: ``SSIS_BIN_DIR`` names their folder
(default: host-tests/target/<host>/release of this checkout). Without them the comparisons
skip, unless ``SSIS_REQUIRE_CLI=1`` (the test command sets it), when they fail.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path
from typing import Callable

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _bindir() -> Path:
    if os.environ.get("SSIS_BIN_DIR"):
        return Path(os.environ["SSIS_BIN_DIR"])
    for d in sorted((ROOT / "host-tests" / "target").glob("*/release")) + [ROOT / "host-tests/target/release"]:
        if (d / "ssis-sim").exists():
            return d
    return ROOT / "host-tests/target/release"


class Cli:
    """Runs a tool; ``json(...)`` adds ``--json`` and returns the object it prints."""

    def __init__(self, bindir: Path) -> None:
        self.bindir = bindir

    def run(self, tool: str, *args: object, check: bool = True) -> subprocess.CompletedProcess:
        p = subprocess.run([str(self.bindir / tool), *map(str, args)], capture_output=True, text=True)
        if check and p.returncode != 0:
            raise AssertionError(f"{tool} {args}: exit {p.returncode}\n{p.stderr}")
        return p

    def json(self, tool: str, *args: object, check: bool = True) -> dict:
        return json.loads(self.run(tool, *args, "--json", check=check).stdout)


@pytest.fixture(scope="session")
def cli() -> Cli:
    d = _bindir()
    if not (d / "ssis-sim").exists():
        msg = f"the command-line tools are not built in {d} (cd host-tests && cargo build --release)"
        if os.environ.get("SSIS_REQUIRE_CLI") == "1":
            pytest.fail(msg)
        pytest.skip(msg)
    return Cli(d)


@pytest.fixture(scope="session")
def root() -> Path:
    return ROOT


@pytest.fixture(scope="session")
def short_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first 90 s of the committed Basilisk log (truth every 20th row)."""
    src = ROOT / "examples/basilisk/leo-nadir-280s.csv"
    out = tmp_path_factory.mktemp("log") / "leo-90s.csv"
    with open(src) as f, open(out, "w") as g:
        n = 0
        for line in f:
            if line[0].isdigit():
                n += 1
                if n > 18_000:
                    break
            g.write(line)
    return out


CAMPAIGN = """format = "ssis-mc-campaign/1"
name = "{name}"
scenario = "{scenario}"
runs = {runs}
seed = 11
duration_s = {duration_s}
loop = "{loop}"

[[disperse]]
table = "fog.bias_rad_s"
dist = "normal"

[[disperse]]
scenario = "star_tracker.latency_ms"
dist = "uniform"
low = -10.0
high = 10.0

[[fault]]
kind = "fog-lost"
probability = 0.2
window_s = [{fault_from_s}, {fault_to_s}]

[indices]
from_s = {from_s}
time_fraction = 0.99

[[indices.index]]
kind = "AKE"

[[indices.index]]
kind = "RKE"
window_s = {window_s}

[[indices.index]]
kind = "KDE"
window_s = {window_s}
separation_s = {separation_s}
"""


def campaign_text(runs: int, duration_s: float, name: str = "c", loop: str = "open") -> str:
    """The Monte Carlo tests' campaign over host-tests/scenarios/qemu-flight.toml: the FOG
    biases and the tracker's latency (±10 ms) dispersed, a FOG lost with probability 0.2
    between 30 % and 60 % of the flight, the knowledge indices from 20 % of it (RKE and
    KDE over a tenth of it, KDE's separation 30 %), each run's the 0.99 quantile over time."""
    return CAMPAIGN.format(
        name=name, scenario=ROOT / "host-tests/scenarios/qemu-flight.toml", runs=runs, duration_s=duration_s,
        loop=loop, fault_from_s=duration_s * 0.3, fault_to_s=duration_s * 0.6, from_s=duration_s * 0.2,
        window_s=duration_s * 0.1, separation_s=duration_s * 0.3,
    )


@pytest.fixture
def campaign(tmp_path: Path) -> Callable[..., Path]:
    """Writes :func:`campaign_text` (the same arguments) to ``<name>.toml`` in the test's
    folder and returns its path."""

    def write(runs: int, duration_s: float, name: str = "c", loop: str = "open") -> Path:
        p = tmp_path / f"{name}.toml"
        p.write_text(campaign_text(runs, duration_s, name, loop))
        return p

    return write


@pytest.fixture(name="campaign_text")
def campaign_text_fixture() -> Callable[..., str]:
    """:func:`campaign_text`, for tests that hand the text to the native module."""
    return campaign_text
