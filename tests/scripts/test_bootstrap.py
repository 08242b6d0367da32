"""scripts/bootstrap.sh is idempotent: a second run with nothing changed rebuilds nothing.

Every step prints a `[bootstrap] ...` line when (and only when) it does work,
so an idle run prints nothing and leaves every step stamp untouched.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
STAMPS = ROOT / ".venv" / ".bootstrap"


def test_second_run_does_nothing() -> None:
    subprocess.run(["bash", str(ROOT / "scripts" / "bootstrap.sh")], check=True, timeout=600)
    before = {p.name: (p.read_text(), p.stat().st_mtime_ns) for p in STAMPS.iterdir()}
    assert {"deps", "msgs", "package", "numba"} <= set(before)
    run = subprocess.run(["bash", str(ROOT / "scripts" / "bootstrap.sh")], capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert "[bootstrap]" not in run.stderr, f"idle run did work:\n{run.stderr}"
    after = {p.name: (p.read_text(), p.stat().st_mtime_ns) for p in STAMPS.iterdir()}
    assert after == before
