"""The type stubs of the native module are true to it (mypy's stubtest compares every
name, signature and property with the module as built), and the package's Python modules
type-check against them under ``mypy --strict`` (a wrapper that returns what the stub
does not promise fails)."""

import subprocess
import sys
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "ssis"


def test_stubs_match_the_native_module():
    pytest.importorskip("mypy")
    p = subprocess.run(
        [sys.executable, "-m", "mypy.stubtest", "ssis._ssis", "--ignore-missing-stub"],
        capture_output=True,
        text=True,
    )
    assert p.returncode == 0, p.stdout + p.stderr


def test_package_passes_mypy_strict_against_the_stubs():
    pytest.importorskip("mypy")
    files = [str(PKG / f) for f in ("_ssis.pyi", "__init__.py", "cal.py", "lab.py")]
    p = subprocess.run(
        [sys.executable, "-m", "mypy", "--strict", "--no-incremental", *files],
        capture_output=True,
        text=True,
    )
    assert p.returncode == 0, p.stdout + p.stderr
