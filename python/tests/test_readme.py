"""The examples of python/README.md and README.md run as written, from the repository root.

Each ```python block of the two pages is run in a fresh namespace with the repository root
as the working directory; what it prints is checked to hold the figures the text promises
(the replay's attitude error beside its limit), so a block that runs but says nothing
useful fails too.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def python_blocks(page: Path) -> list[tuple[int, str]]:
    """The ```python blocks of a markdown page, with the line each starts on."""
    blocks, lines = [], page.read_text(encoding="utf-8").splitlines()
    i = 0
    while i < len(lines):
        if lines[i].strip() == "```python":
            end = next(k for k in range(i + 1, len(lines)) if lines[k].strip() == "```")
            blocks.append((i + 2, "\n".join(lines[i + 1 : end]) + "\n"))
            i = end
        i += 1
    return blocks


PAGES = [ROOT / "python" / "README.md", ROOT / "README.md"]
CASES = [(p, line, code) for p in PAGES for line, code in python_blocks(p)]


def test_each_page_has_its_example() -> None:
    assert any(p.name == "README.md" and p.parent.name == "python" for p, _, _ in CASES)
    first = python_blocks(ROOT / "python" / "README.md")[0][1]
    assert len([l for l in first.splitlines() if l.strip()]) <= 12, "the first example stays about ten lines"


@pytest.mark.parametrize("page,line,code", CASES, ids=[f"{p.relative_to(ROOT)}:{l}" for p, l, _ in CASES])
def test_readme_example_runs(page: Path, line: int, code: str) -> None:
    out = io.StringIO()
    cwd = os.getcwd()
    os.chdir(ROOT)
    try:
        with contextlib.redirect_stdout(out):
            exec(compile(code, f"{page.relative_to(ROOT)}:{line}", "exec"), {"__name__": "__readme__"})
    finally:
        os.chdir(cwd)
    printed = out.getvalue()
    assert printed.strip(), f"{page.name}:{line} printed nothing"
    if "attitude error 3σ" in printed:
        # The replay of the Basilisk log: three per-axis figures within 1.1x the limit's.
        err = [float(x) for x in re.findall(r"[-+]?\d+\.\d+", printed.split("attitude error 3σ")[1].splitlines()[0])]
        lim = [float(x) for x in re.findall(r"[-+]?\d+\.\d+", printed.split("estimation limit 3σ")[1].splitlines()[0])]
        assert len(err) == 3 and len(lim) == 3, printed
        assert all(0 < e <= 1.1 * max(lim) for e in err), printed
