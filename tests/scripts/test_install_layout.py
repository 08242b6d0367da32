"""The installed layout is what `ros2 run` and ROS tools expect.

Guarantees proved here, for the venv install made by scripts/bootstrap.sh (the
same paths colcon creates through setup.cfg/data_files):
- the ament index lists circle_collision_ros and circle_collision_msgs;
- share/circle_collision_ros holds package.xml, the launch files and the config;
- every console script declared in setup.py is an executable file under
  <prefix>/lib/circle_collision_ros/, found the way `ros2 run` finds it;
- each of them starts (``--help``) without a ROS graph.
"""
from __future__ import annotations

import os
import runpy
import subprocess
import sys
from pathlib import Path

import pytest
import setuptools
from ament_index_python.packages import get_package_prefix, get_package_share_directory

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = "circle_collision_ros"


def _setup_kwargs() -> dict:
    """What setup.py declares, read by running it with setup() captured."""
    captured: dict = {}
    original = setuptools.setup
    setuptools.setup = lambda **kw: captured.update(kw)
    cwd = os.getcwd()
    try:
        os.chdir(ROOT)
        runpy.run_path("setup.py")
    finally:
        setuptools.setup = original
        os.chdir(cwd)
    return captured


SETUP = _setup_kwargs()
CONSOLE_SCRIPTS = [spec.split("=")[0].strip() for spec in SETUP["entry_points"]["console_scripts"]]


@pytest.fixture(autouse=True)
def _ament_prefix_is_venv(monkeypatch: pytest.MonkeyPatch) -> None:
    # A ROS user points AMENT_PREFIX_PATH at the install prefix; here that is the venv.
    monkeypatch.setenv("AMENT_PREFIX_PATH", sys.prefix)


def test_ament_index_lists_both_packages() -> None:
    assert Path(get_package_prefix(PACKAGE)) == Path(sys.prefix)
    assert Path(get_package_prefix("circle_collision_msgs")) == Path(sys.prefix)


def test_share_holds_package_xml_launch_and_config() -> None:
    share = Path(get_package_share_directory(PACKAGE))
    assert (share / "package.xml").read_text() == (ROOT / "package.xml").read_text()
    for dest, files in SETUP["data_files"]:
        for f in files:
            assert (Path(sys.prefix) / dest / Path(f).name).is_file(), (
                f"{f} not installed to {dest}"
            )
    assert list((share / "launch").glob("*.launch.py")), "no launch file installed"
    assert list((share / "config").glob("*.yaml")), "no parameter file installed"


def _ros2_run_executables(package: str) -> set[str]:
    """The executables `ros2 run <package>` can start (ros2pkg's get_executable_paths)."""
    lib = Path(get_package_prefix(package)) / "lib" / package
    return {p.name for p in lib.iterdir() if p.is_file() and os.access(p, os.X_OK)}


def test_every_console_script_is_a_ros2_run_executable() -> None:
    assert CONSOLE_SCRIPTS, "setup.py declares no console scripts"
    assert set(CONSOLE_SCRIPTS) <= _ros2_run_executables(PACKAGE)


@pytest.mark.parametrize("name", CONSOLE_SCRIPTS)
def test_console_script_starts(name: str) -> None:
    exe = Path(get_package_prefix(PACKAGE)) / "lib" / PACKAGE / name
    out = subprocess.run([str(exe), "--help"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "usage" in (out.stdout + out.stderr).lower()
