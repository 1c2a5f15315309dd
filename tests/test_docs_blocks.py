"""Every ``bash`` and ``python`` block of the README and docs/ runs as pasted from the
repository root: ``python -m pytest -m docs`` (blocks marked ``<!-- slow -->`` on the line
before their fence, the set-up and training, also carry the ``slow`` mark: ``-m "docs and
slow"``). A block that reads ``../shared`` runs where the benchmark files are (beside the
repository, or ``$RLPGO_DATASETS``) and is skipped elsewhere; the others, the README's first
ones among them, run in a fresh clone with nothing beside it. Paths under /tmp/ are moved into
the test's own folder so that runs never meet each other's outputs; nothing may be left in
the checkout. Where a ``text`` block follows a block, it is what the block prints: the lines
must match, each number standing for any number (timings differ from run to run)."""

from __future__ import annotations

import difflib
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import DATASETS

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
SHARED = "../shared/datasets"
_FENCE = re.compile(r"^```(\w*)\s*$")
_TMP = re.compile(r"/tmp/[\w.@-]+")
_NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")
# the staircase's rate-limited lines (at most one every 2 s): how many depends on the machine
_RATE_LIMITED = re.compile(r"rank \d+: (?:iteration \d+,|verifying S,)")


def _fenced(lines: list[str]) -> list[tuple[int, int, str]]:
    """(opening line index, closing line index, language) of each fenced block."""
    found, k = [], 0
    while k < len(lines):
        opened = _FENCE.match(lines[k])
        if not opened:
            k += 1
            continue
        end = next(e for e in range(k + 1, len(lines)) if lines[e].startswith("```"))
        found.append((k, end, opened.group(1)))
        k = end + 1
    return found


def _code_blocks() -> list[tuple[str, int, str, str, str | None, bool]]:
    """(page, line, language, code, documented output or None, slow) of every bash and
    python block, in reading order: the README, then docs/ by name. The documented output
    is the ``text`` block after it, with only blank lines between."""
    found = []
    for page in PAGES:
        lines = page.read_text().splitlines()
        fences = _fenced(lines)
        for n, (k, end, language) in enumerate(fences):
            if language not in ("bash", "python"):
                continue
            output = None
            if n + 1 < len(fences):
                k2, end2, language2 = fences[n + 1]
                if language2 == "text" and not any(x.strip() for x in lines[end + 1:k2]):
                    output = "\n".join(lines[k2 + 1:end2])
            slow = k > 0 and lines[k - 1].strip() == "<!-- slow -->"
            found.append((str(page.relative_to(ROOT)), k + 1, language,
                          "\n".join(lines[k + 1:end]) + "\n", output, slow))
    return found


BLOCKS = _code_blocks()


def _params() -> list:
    return [pytest.param(language, code, output, id=f"{page}:{line}",
                         marks=[pytest.mark.docs] + ([pytest.mark.slow] if slow else []))
            for page, line, language, code, output, slow in BLOCKS]


def _checkout_files() -> set[str]:
    listed = subprocess.run(["git", "ls-files", "--others", "--exclude-standard"], cwd=ROOT,
                            capture_output=True, text=True, check=True).stdout
    return set(listed.split())


def _shape(text: str) -> list[str]:
    """The lines of ``text`` as compared: every number one '#', runs of spaces one space,
    the rate-limited progress lines left out, blank lines at either end dropped."""
    shaped = [" ".join(_NUMBER.sub("#", line).split()) for line in text.splitlines()
              if not _RATE_LIMITED.search(line)]
    while shaped and not shaped[0]:
        shaped.pop(0)
    while shaped and not shaped[-1]:
        shaped.pop()
    return shaped


@pytest.mark.parametrize(("language", "code", "output"), _params())
def test_block_runs_as_pasted(request, tmp_path, language, code, output):
    if SHARED in code and not DATASETS.is_dir():
        pytest.skip(f"the block reads {SHARED}: {DATASETS} not found (set RLPGO_DATASETS)")
    code = code.replace("/tmp/", f"{tmp_path}/").replace(SHARED, str(DATASETS))
    # the set-up and training blocks run for minutes (400 training episodes: more than 5 on
    # 2 cores); the others have 5 minutes
    timeout = 1800 if request.node.get_closest_marker("slow") else 300
    before = _checkout_files()
    command = ["bash", "-euo", "pipefail", "-c", code] if language == "bash" else \
        [sys.executable, "-c", code]
    # stdout and stderr in one stream, unbuffered: in the order a terminal shows them
    done = subprocess.run(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                          text=True, timeout=timeout, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    printed = done.stdout.replace(f"{tmp_path}/", "/tmp/").replace(str(DATASETS), SHARED)
    assert done.returncode == 0, printed
    assert "Traceback" not in printed
    assert _checkout_files() == before, "a block left files in the checkout"
    if output is not None:
        documented, actual = _shape(output), _shape(printed)
        assert documented == actual, "the documented output differs from what is printed:\n" + \
            "\n".join(difflib.unified_diff(documented, actual, "documented", "printed",
                                           lineterm=""))


def test_no_two_blocks_share_a_tmp_path():
    """Pasting the README and then docs/ in order, no block meets another's output (a
    second write of a path stops with 'exists; give --overwrite')."""
    first_seen: dict[str, str] = {}
    for page, line, _, code, _, _ in BLOCKS:
        for path in set(_TMP.findall(code)):
            where = f"{page}:{line}"
            assert first_seen.setdefault(path, where) == where, \
                f"{path} is written by {first_seen[path]} and by {where}"


def test_the_readme_runs_without_the_benchmark_files():
    """A fresh clone with nothing beside it runs the README's blocks but the set-up and the
    test suite's (slow-marked), on GTSAM's example data."""
    readme = [code for page, _, _, code, _, slow in BLOCKS if page == "README.md" and not slow]
    assert readme and not any(SHARED in code or "../shared" in code for code in readme)
