"""Fixtures: the command-line tools the package is compared with.

The tools are the host workspace's release binaries: ``SSIS_BIN_DIR`` names their folder
(default: host-tests/target/<host>/release of this checkout). Without them the comparisons
skip, unless ``SSIS_REQUIRE_CLI=1`` (the test command sets it), when they fail.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

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
