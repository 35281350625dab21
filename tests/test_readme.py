"""The README's Python snippets run as written: each on its own, in a fresh interpreter, from a
folder that holds only the sample logs (so a snippet that leans on another's imports, or on a
file the README does not name, fails here)."""
from __future__ import annotations

import re
import subprocess
import sys

import pytest

from conftest import ROOT

README = ROOT / "README.md"
SNIPPETS = re.findall(r"^```python\n(.*?)^```", README.read_text(encoding="utf-8"), flags=re.S | re.M)


def test_readme_has_snippets():
    assert len(SNIPPETS) >= 3


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(SNIPPETS)), ids=lambda i: f"snippet{i + 1}")
def test_readme_snippet_runs(index, tmp_path):
    (tmp_path / "sample_logs").symlink_to(ROOT / "sample_logs")
    script = tmp_path / "snippet.py"
    script.write_text(SNIPPETS[index], encoding="utf-8")
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, f"README snippet {index + 1} failed:\n{done.stderr[-3000:]}"


def test_ci_runs_the_readme_test_command():
    quick_start = README.read_text(encoding="utf-8").split("## Quick start", 1)[1]
    commands = re.search(r"```sh\n(.*?)```", quick_start, flags=re.S).group(1).strip().splitlines()
    assert len(commands) == 2, "the Quick start has exactly two commands"
    assert commands[1] in (ROOT / ".ci" / "run").read_text(encoding="utf-8")
