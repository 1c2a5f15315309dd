"""Every ``bash`` and ``python`` block of the README and docs/ runs as pasted from the
repository root, ``../shared`` beside it: ``python -m pytest -m docs`` (blocks marked
``<!-- slow -->`` on the line before their fence, the set-up and training, also carry the
``slow`` mark: ``-m "docs and slow"``). Paths under /tmp/ are moved into the test's own folder so
that runs never meet each other's outputs; nothing may be left in the checkout."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
_FENCE = re.compile(r"^```(\w*)\s*$")


def _blocks() -> list:
    found = []
    for page in PAGES:
        lines = page.read_text().splitlines()
        k = 0
        while k < len(lines):
            opened = _FENCE.match(lines[k])
            if not opened:
                k += 1
                continue
            end = next(e for e in range(k + 1, len(lines)) if lines[e].startswith("```"))
            language = opened.group(1)
            if language in ("bash", "python"):
                slow = k > 0 and lines[k - 1].strip() == "<!-- slow -->"
                marks = [pytest.mark.docs] + ([pytest.mark.slow] if slow else [])
                found.append(pytest.param(language, "\n".join(lines[k + 1:end]) + "\n",
                                          id=f"{page.relative_to(ROOT)}:{k + 1}", marks=marks))
            k = end + 1
    return found


def _checkout_files() -> set[str]:
    listed = subprocess.run(["git", "ls-files", "--others", "--exclude-standard"], cwd=ROOT,
                            capture_output=True, text=True, check=True).stdout
    return set(listed.split())


@pytest.mark.skipif(not (ROOT.parent / "shared" / "datasets").is_dir(),
                    reason="the docs read ../shared/datasets")
@pytest.mark.parametrize(("language", "code"), _blocks())
def test_block_runs_as_pasted(request, tmp_path, language, code):
    code = code.replace("/tmp/", f"{tmp_path}/")
    # the set-up and training blocks run for minutes (400 training episodes: more than 5 on
    # 2 cores); the others have 5 minutes
    timeout = 1800 if request.node.get_closest_marker("slow") else 300
    before = _checkout_files()
    command = ["bash", "-euo", "pipefail", "-c", code] if language == "bash" else \
        [sys.executable, "-c", code]
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, f"{done.stdout}\n{done.stderr}"
    assert "Traceback" not in done.stderr
    assert _checkout_files() == before, "a block left files in the checkout"
