"""README.md must hold the exact test command that .ci/run executes."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_ci_runs_the_readme_test_command():
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    cmd = [ln for ln in ci if ln.strip() and not ln.startswith(("#", "set ", "cd ", "echo "))]
    cmd = [ln for ln in cmd if not ln.startswith("#!")]
    assert len(cmd) == 1, cmd
    assert cmd[0].strip() in (ROOT / "README.md").read_text()
