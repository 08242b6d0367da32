"""`replay` on a corpus: discovery, summary, exit code, JUnit, progress, dead workers, Ctrl-C, Dask.

Guarantees proved here (all through the real `replay` command in a subprocess):
- any mix of bag dirs, parent folders (searched recursively), .mcap files and
  globs is replayed; each bag gets one summary row and one JUnit testcase;
  unreadable, truncated and non-bag paths are one `unreadable` line each and
  the other bags still run; exit 0 all identical / 1 mismatch / 2 unreadable;
- a worker killed while replaying a bag costs that bag one attempt: killed
  once it is retried and identical, killed twice it is `failed`, and no other
  result is lost;
- Ctrl-C prints the partial summary (finished bags plus `not run`), exit 130;
- a progress bar on a terminal, plain lines otherwise;
- the same corpus on a Dask LocalCluster (addressed like a real cluster) gives
  the same verdicts, and killing its workers mid-run loses no bag.
The killed-worker tests (local and Dask) are marked stress: they run under --stress (CI);
the default run keeps one Dask run (the only test of --cluster).
"""

from __future__ import annotations

import fcntl
import os
import pty
import re
import shutil
import signal
import struct
import subprocess
import sys
import termios
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

REPLAY = [sys.executable, "-m", "circle_collision_ros.recording.replay"]


def _rows(stdout: str) -> dict[str, str]:
    """Summary rows: bag path -> verdict (with the attempts note when retried)."""
    rows = {}
    lines = stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("bag "))
    for line in lines[start + 1 :]:
        m = re.match(
            r"^(\S+)\s+\d+\s+\d+\s+\d+\s+\S+\s+(identical|mismatch|unreadable|failed|not run)(.*)$",
            line,
        )
        if not m:
            break
        rows[m.group(1)] = m.group(2) + m.group(3)
    return rows


def _replay(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(REPLAY + list(args), capture_output=True, text=True, timeout=timeout)


def test_mixed_corpus_summary_exit_code_and_junit(small_corpus, tmp_path: Path) -> None:
    c = small_corpus
    junit = tmp_path / "replay.xml"
    run = _replay(
        str(c.root / "robot_a"),  # parent folder: two bags
        str(c.root / "robot_b" / "*"),  # glob: a nested folder and a bag
        str(c.truncated),
        str(c.not_a_bag),  # bad files named explicitly
        str(tmp_path / "missing"),
        "--jobs",
        "2",
        "--junit-xml",
        str(junit),
    )
    assert run.returncode == 2, run.stdout + run.stderr
    assert "Traceback" not in run.stderr
    rows = _rows(run.stdout)
    assert rows == {**{str(b): "identical" for b in c.identical}, str(c.mismatch): "mismatch",
                    str(c.truncated): "unreadable", str(c.not_a_bag): "unreadable",
                    str(tmp_path / "missing"): "unreadable"}
    # One line naming each bad path, and the first difference of the mismatch.
    assert re.search(rf"^unreadable: {re.escape(str(c.truncated))}: truncated", run.stdout, re.M)
    assert re.search(
        rf"^unreadable: {re.escape(str(c.not_a_bag))}: not an MCAP file", run.stdout, re.M
    )
    assert re.search(
        rf"^unreadable: {re.escape(str(tmp_path / 'missing'))}: no such file", run.stdout, re.M
    )
    assert re.search(
        rf"^mismatch: {re.escape(str(c.mismatch))}: \d+ difference\(s\); first: prediction #\d+: "
        r"pair \(.*\) differs",
        run.stdout,
        re.M,
    )
    assert re.search(r"^total: 7 bags: 3 identical, 1 mismatch, 3 unreadable, 0 failed; \d+ inputs",
                     run.stdout, re.M)
    assert re.search(r"^wall time: [\d.]+ s \(2 local workers\)$", run.stdout, re.M)
    assert len(re.findall(r"^\[\d/7\] ", run.stdout, re.M)) == 7  # plain progress lines, not a bar

    suite = ET.parse(junit).getroot().find("testsuite")
    assert (suite.get("tests"), suite.get("failures"), suite.get("errors")) == ("7", "1", "3")
    cases = {case.get("name"): case for case in suite.iter("testcase")}
    assert set(cases) == set(rows)
    assert cases[str(c.mismatch)].find("failure") is not None
    assert "differs" in cases[str(c.mismatch)].find("failure").get("message")
    assert cases[str(c.truncated)].find("error").get("type") == "unreadable"
    assert all(
        cases[str(b)].find("failure") is None and cases[str(b)].find("error") is None
        for b in c.identical
    )


def test_exit_codes_identical_and_mismatch(small_corpus, good_corpus: Path) -> None:
    ok = _replay(str(good_corpus), "--jobs", "2")
    assert ok.returncode == 0, ok.stdout + ok.stderr
    assert set(_rows(ok.stdout).values()) == {"identical"}
    bad = _replay(str(good_corpus), str(small_corpus.mismatch), "--jobs", "2")
    assert bad.returncode == 1, bad.stdout + bad.stderr
    assert sorted(_rows(bad.stdout).values()) == ["identical"] * 3 + ["mismatch"]


def test_single_bag_keeps_its_own_output(small_corpus) -> None:
    run = _replay(str(small_corpus.identical[0]))
    assert run.returncode == 0, run.stderr
    assert "messages replayed:" in run.stdout and "bag " not in run.stdout


def _kill_on_start(args: list[str], kills: dict[str, int]) -> tuple[int, str, str]:
    """Run replay -v and SIGKILL the worker that starts bag B, kills[B] times."""
    proc = subprocess.Popen(
        REPLAY + args + ["--verbose"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    out = []
    for line in proc.stdout:
        out.append(line)
        m = re.match(r"^start (\S+) on worker (\d+)$", line.strip())
        if m and kills.get(m.group(1), 0) > 0:
            kills[m.group(1)] -= 1
            os.kill(int(m.group(2)), signal.SIGKILL)
    proc.wait(timeout=60)
    return proc.returncode, "".join(out), proc.stderr.read()


@pytest.mark.stress
def test_a_killed_worker_is_retried_once_then_the_bag_fails(small_corpus, tmp_path: Path) -> None:
    from tests.recording.conftest import DATA, copy_bag

    once = copy_bag(DATA / "plain_2d", tmp_path / "killed_once")  # whole bags: ~1 s of work
    twice = copy_bag(DATA / "spheres_3d", tmp_path / "killed_twice")
    others = [str(b) for b in small_corpus.identical]
    code, out, err = _kill_on_start(
        [str(once), str(twice), *others, "--jobs", "2"], {str(once): 1, str(twice): 2}
    )
    rows = _rows(out)
    assert code == 2, out + err
    assert rows[str(once)] == "identical (attempts: 2)"
    assert rows[str(twice)] == "failed (attempts: 2)"
    assert all(rows[b] == "identical" for b in others)
    assert re.search(
        rf"^retry {re.escape(str(once))}: worker \d+ died \(signal SIGKILL\)", out, re.M
    )
    assert re.search(
        rf"^failed: {re.escape(str(twice))}: worker \d+ died \(signal SIGKILL\) on each of 2",
        out,
        re.M,
    )


def test_ctrl_c_prints_the_partial_summary(small_corpus, tmp_path: Path) -> None:
    from tests.recording.conftest import DATA

    # Enough distinct bags that the replay is still running when the signal arrives (a bag
    # given twice is replayed once): 40 copies of the recorded data, ~0.1 s of work each.
    copies = []
    for k in range(40):
        name = ("plain_2d", "spheres_3d", "bad_inputs_2d")[k % 3]
        copies.append(shutil.copytree(DATA / name, tmp_path / f"copy_{k:02d}_{name}"))
    bags = [str(b) for b in small_corpus.identical] + [str(c) for c in copies]
    proc = subprocess.Popen(
        REPLAY + bags + ["--jobs", "1"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    first = proc.stdout.readline()
    assert first.startswith("[1/"), first
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, out + err
    assert "Traceback" not in err and "interrupted;" in err
    verdicts = list(_rows(out).values())
    assert "identical" in verdicts and "not run" in verdicts
    assert re.search(r"^wall time:", out, re.M)


def test_progress_bar_on_a_terminal(good_corpus: Path) -> None:
    controller, terminal = pty.openpty()
    fcntl.ioctl(terminal, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))  # 100 columns
    proc = subprocess.Popen(REPLAY + [str(good_corpus), "--jobs", "2"], stdout=subprocess.PIPE,
                            stderr=terminal, text=True)
    os.close(terminal)
    shown = b""
    while True:
        try:
            chunk = os.read(controller, 4096)
        except OSError:  # EIO: the child closed the terminal
            break
        if not chunk:
            break
        shown += chunk
    out = proc.communicate(timeout=60)[0]
    os.close(controller)
    assert proc.returncode == 0
    assert b"3/3" in shown and b"100%" in shown and b"bag" in shown  # tqdm's bar
    assert not re.search(r"^\[\d/3\]", out, re.M)  # no plain progress lines
    assert len(_rows(out)) == 3


# ---------------------------------------------------------------- Dask


@pytest.fixture(scope="module")
def dask_cluster():
    """A local Dask cluster of 2 worker processes, addressed like a remote one.

    allowed-failures 0: a task whose worker dies comes back to the client at
    once, so the client's retry-once rule is the only retry (as locally).
    """
    import dask
    from distributed import LocalCluster

    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                          host="127.0.0.1") as cluster:
            yield cluster


def test_dask_cluster_gives_the_same_verdicts(small_corpus, dask_cluster, tmp_path: Path) -> None:
    c = small_corpus
    junit = tmp_path / "dask.xml"
    run = _replay(
        str(c.root), "--cluster", dask_cluster.scheduler_address, "--junit-xml", str(junit)
    )
    assert run.returncode == 2, run.stdout + run.stderr
    assert _rows(run.stdout) == {**{str(b): "identical" for b in c.identical},
                                 str(c.mismatch): "mismatch", str(c.truncated): "unreadable",
                                 str(c.not_a_bag): "unreadable"}
    assert f"(Dask cluster {dask_cluster.scheduler_address})" in run.stdout
    assert ET.parse(junit).getroot().get("tests") == "6"


@pytest.mark.stress
def test_dask_workers_killed_mid_run_lose_no_bag(good_corpus: Path, dask_cluster) -> None:
    from distributed import Client

    from tests.recording.conftest import DATA

    bags = [str(good_corpus)] + [
        str(DATA / name) for name in ("plain_2d", "spheres_3d", "bad_inputs_2d")
    ]
    with Client(dask_cluster.scheduler_address) as client:
        client.run(lambda: __import__("circle_collision_ros.recording.replay"))  # warm the workers
        pids = list(client.run(os.getpid).values())
    proc = subprocess.Popen(REPLAY + bags + ["--cluster", dask_cluster.scheduler_address],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = proc.stdout.readline()
    assert first.startswith("[1/6]"), first
    for pid in pids:  # 5 bags still to go: both workers hold one
        os.kill(pid, signal.SIGKILL)
    out, err = proc.communicate(timeout=300)
    out = first + out
    assert proc.returncode == 0, out + err
    rows = _rows(out)
    assert len(rows) == 6 and all(v.startswith("identical") for v in rows.values())
    assert re.search(r"^retry \S+: worker died", out, re.M)
    assert any("attempts: 2" in v for v in rows.values())


def test_find_bags_follows_symlinks_once(small_corpus, tmp_path: Path) -> None:
    from circle_collision_ros.recording.corpus import find_bags

    links = tmp_path / "links"
    (links / "nested").mkdir(parents=True)
    (links / "a").symlink_to(small_corpus.identical[0])
    (links / "nested" / "b").symlink_to(small_corpus.identical[1])
    (links / "nested" / "again").symlink_to(small_corpus.identical[0])  # same bag twice
    (links / "nested" / "loop").symlink_to(links)  # a cycle
    bags, problems = find_bags([str(links)])
    assert bags == [str(links / "a"), str(links / "nested" / "b")] and problems == []
