"""The shipped Fast DDS profile for large scenes (README, "Large scenes").

Guarantees proved here:
- the profile is installed with the package and is what the executables load
  when the user has not chosen a profile;
- the user's own FASTDDS_DEFAULT_PROFILES_FILE (or the deprecated FASTRTPS_ name)
  is never replaced;
- with the profile on both sides, 1 MB CircleStateArray frames cross from one
  process to another to a best-effort reader (the node's default QoS): counts, not timings
  (a best-effort count depends on the machine's load: these measurements are stress runs;
  the loss count through the node is exact in tests/node/test_stream.py, queue overrun).
"""
from __future__ import annotations

import importlib.util
import os
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from circle_collision_ros.cli import TransportProfile, use_large_scene_transport

ROOT = Path(__file__).resolve().parents[2]


def _bench_module():
    spec = importlib.util.spec_from_file_location(
        "transport_delivery", ROOT / "bench" / "transport_delivery.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_profile_is_installed_and_gives_a_large_shared_memory_segment() -> None:
    installed = (
        Path(sys.prefix) / "share" / "circle_collision_ros" / "config" / TransportProfile.FILE_NAME
    )
    assert installed.is_file(), "setup.py data_files must install config/*.xml"
    path = TransportProfile.path()
    assert path is not None and path.is_file()
    ns = {"f": "http://www.eprosima.com"}
    root = ET.parse(path).getroot()
    participant = root.find("f:profiles/f:participant", ns)
    assert participant is not None and participant.get("is_default_profile") == "true"
    shm = [
        d
        for d in root.iterfind("f:profiles/f:transport_descriptors/f:transport_descriptor", ns)
        if d.findtext("f:type", namespaces=ns) == "SHM"
    ]
    assert shm and int(shm[0].findtext("f:segment_size", namespaces=ns)) >= 32 * 1024 * 1024
    used = {t.text for t in participant.iterfind("f:rtps/f:userTransports/f:transport_id", ns)}
    assert shm[0].findtext("f:transport_id", namespaces=ns) in used
    # UDPv4 stays, so a user who sets ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET still reaches other
    # hosts.
    assert any(
        d.findtext("f:type", namespaces=ns) == "UDPv4"
        for d in root.iterfind("f:profiles/f:transport_descriptors/f:transport_descriptor", ns)
    )


def test_the_users_profile_setting_always_wins(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(TransportProfile.ENV, "/their/profile.xml")
    assert use_large_scene_transport() == "/their/profile.xml"
    assert os.environ[TransportProfile.ENV] == "/their/profile.xml"

    monkeypatch.delenv(TransportProfile.ENV)
    monkeypatch.setenv(TransportProfile.DEPRECATED_ENV, "/their/old_profile.xml")
    assert use_large_scene_transport() == "/their/old_profile.xml"
    assert TransportProfile.ENV not in os.environ  # no second profile beside theirs

    monkeypatch.delenv(TransportProfile.DEPRECATED_ENV)
    assert use_large_scene_transport() == str(TransportProfile.path())
    assert os.environ[TransportProfile.ENV] == str(TransportProfile.path())


@pytest.mark.stress
def test_one_megabyte_frames_cross_processes_best_effort_with_the_profile() -> None:
    bench = _bench_module()
    sent = 30
    delivery = bench.run_pair(
        size_kb=1000, count=sent, rate=10.0, pub_profile=True, sub_profile=True, reliable=False
    )
    # Counts, not timings: with Fast DDS's defaults this size arrived 0-11 times in 60
    # (bench/transport_delivery.py); a frame or two may still be lost on a loaded machine.
    assert delivery.received >= sent - 2, f"only {delivery.received} of {sent} 1 MB frames arrived"
    assert delivery.accounted, delivery


@pytest.mark.stress
def test_the_loss_monitor_counts_every_frame_lost_without_the_profile() -> None:
    """InputLossMonitor's count is exact: received + counted missing + (lost before the first or
    after the last received frame, which no signal can see) = sent. Without the profile on the
    publisher, 1 MB best-effort frames are lost, and the monitor must say how many."""
    bench = _bench_module()
    delivery = bench.run_pair(
        size_kb=1000, count=30, rate=10.0, pub_profile=False, sub_profile=False, reliable=False
    )
    assert delivery.accounted, delivery
    if delivery.received >= 2:  # a count needs a frame after the gap
        assert (
            delivery.detected_missing == delivery.sent - delivery.received - delivery.undetectable
        )


@pytest.mark.stress
def test_no_loss_is_reported_for_small_frames() -> None:
    bench = _bench_module()
    delivery = bench.run_pair(
        size_kb=20, count=100, rate=50.0, pub_profile=True, sub_profile=True, reliable=False
    )
    assert delivery.detected_missing == 0 and delivery.accounted, delivery


# -- through collision_node ---------------------------------------------------------------------
def _node_diagnostics(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, profile: str | None, **params
) -> dict:
    """Start collision_node with FASTDDS_DEFAULT_PROFILES_FILE = `profile` (None: unset).

    Returns its /diagnostics.
    """
    from tests.reliability.node_process import Client, NodeProcess

    monkeypatch.delenv(TransportProfile.DEPRECATED_ENV, raising=False)
    if profile is None:
        monkeypatch.delenv(TransportProfile.ENV, raising=False)
    else:
        monkeypatch.setenv(TransportProfile.ENV, profile)
    node = NodeProcess(tmp_path / "node.log", marker_rate=0.0, **params)
    client = Client()
    try:
        return client.last_diagnostics(timeout=30.0)
    finally:
        client.close()
        node.stop()


def test_the_node_loads_the_shipped_profile_when_none_is_set(tmp_path, monkeypatch) -> None:
    values = _node_diagnostics(tmp_path, monkeypatch, None)
    assert values["transport_profile"] == str(TransportProfile.path())


def test_the_node_leaves_the_users_profile_in_force(tmp_path, monkeypatch) -> None:
    theirs = tmp_path / "their_profile.xml"
    theirs.write_text(TransportProfile.path().read_text())
    values = _node_diagnostics(tmp_path, monkeypatch, str(theirs))
    assert values["transport_profile"] == str(theirs)


def test_state_reliability_reliable_reports_best_effort_publishers_it_cannot_hear(
    tmp_path, monkeypatch
) -> None:
    from tests.reliability.node_process import Client, NodeProcess

    node = NodeProcess(tmp_path / "node.log", marker_rate=0.0, state_reliability="reliable")
    reliable, best_effort = (
        Client("reliable_tracker"),
        Client("best_effort_tracker", reliable=False),
    )
    try:
        reliable.wait_matched()
        # the node reads publishers from the ROS graph, whose discovery runs apart from the
        # endpoint matching above: either publisher may show up first
        assert reliable.spin(
            30.0,
            lambda: (
                bool(reliable.diagnostics)
                and "best_effort" in reliable.diagnostics[-1].get("input_publishers", "")
                and "reliable" in reliable.diagnostics[-1]["input_publishers"].replace(
                    "best_effort", "")
            ),
        )
        values = reliable.diagnostics[-1]
        assert "1 reliable" in values["input_publishers"], values["input_publishers"]
        assert values["_level"] == 1 and "cannot reach" in values["_message"], values
    finally:
        reliable.close()
        best_effort.close()
        node.stop()


def test_bad_state_reliability_stops_the_node_with_one_line(tmp_path) -> None:
    import subprocess

    from tests.reliability.node_process import EXE

    run = subprocess.run([EXE, "--ros-args", "-p", "state_reliability:=sometimes"],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "state_reliability must be one of" in run.stderr, run.stderr


@pytest.mark.stress
def test_large_frames_lost_by_the_publishers_transport_show_on_diagnostics(
    tmp_path, monkeypatch
) -> None:
    """A publisher without the profile sends 0.7 MB frames best-effort: the node counts what never
    arrived and points to the profile. (With the profile on the publisher nothing is missing:
    test_one_megabyte_frames_cross_processes_best_effort_with_the_profile.)"""
    import subprocess

    from tests.reliability.node_process import Client, NodeProcess

    bench = _bench_module()
    node = NodeProcess(tmp_path / "node.log", marker_rate=0.0)
    client = Client()
    try:
        client.wait_matched()
        publisher = subprocess.Popen(
            [sys.executable, str(ROOT / "bench" / "transport_delivery.py"), "--role", "pub",
             "--bodies", "6000", "--count", "60", "--rate", "30", "--topic", "circle_states"],
            env=bench._profile_env(False),
        )
        publisher.wait(timeout=120)

        def lost() -> bool:
            return bool(client.diagnostics) and int(client.diagnostics[-1]["inputs_missing"]) > 0

        if not client.spin(10.0, lost):
            pytest.skip("this run lost no frames without the profile (nothing to report)")
        values = client.diagnostics[-1]
        assert float(values["largest_input_kb"]) > 600
        assert "fastdds_large_scenes.xml" in "".join(d["_message"] for d in client.diagnostics)
        assert "fastdds_large_scenes.xml" in node.log()
    finally:
        client.close()
        node.stop()
