"""scripts/bootstrap.sh is idempotent: a run with nothing changed rebuilds nothing.

Every step prints a `[bootstrap] ...` line when (and only when) it does work,
so an idle run prints nothing and leaves every step stamp untouched.

The quick run checks the idle run only (scripts/test.sh has just run the bootstrap,
so that costs one idle run, about a second); the stress run also runs
`bootstrap.sh --kernels` (what scripts/test.sh runs) twice.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
STAMPS = ROOT / ".venv" / ".bootstrap"
STEPS = {"deps", "msgs", "package"}


def _stamps() -> dict[str, tuple[str, int]]:
    return {p.name: (p.read_text(), p.stat().st_mtime_ns) for p in STAMPS.iterdir()}


def _run(*args: str, timeout: float) -> subprocess.CompletedProcess:
    run = subprocess.run(["bash", str(ROOT / "scripts" / "bootstrap.sh"), *args],
                         capture_output=True, text=True, timeout=timeout)
    assert run.returncode == 0, run.stdout + run.stderr
    return run


def _assert_idle(*args: str, timeout: float) -> subprocess.CompletedProcess:
    before = _stamps()
    assert STEPS <= set(before)
    run = _run(*args, timeout=timeout)
    assert "[bootstrap]" not in run.stderr, f"idle run did work:\n{run.stderr}"
    assert _stamps() == before
    return run


def test_idle_run_does_nothing() -> None:
    """After a run, the next run prints nothing and touches no stamp.

    One run when the set-up is current (as scripts/test.sh leaves it); if this run did
    work (pytest started without scripts/test.sh after an input changed), a second run
    must then be idle."""
    if not STEPS <= set(_stamps() if STAMPS.is_dir() else {}):
        _run(timeout=600)
    before = _stamps()
    first = _run(timeout=600)
    if "[bootstrap]" not in first.stderr:
        assert _stamps() == before
        return
    _assert_idle(timeout=120)


@pytest.mark.stress
def test_second_run_with_kernels_does_nothing() -> None:
    """What scripts/test.sh runs (`bootstrap.sh --kernels`), twice: the second run does no work."""
    _run("--kernels", timeout=900)
    run = _assert_idle("--kernels", timeout=300)
    assert "compiling" not in run.stdout, run.stdout
