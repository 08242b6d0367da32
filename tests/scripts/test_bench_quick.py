"""The benchmark suite's --quick path produces every file, well-formed.

Runs ``bench/run_all.py --quick --out <tmp>`` once (about a minute: it starts
a collision_node through DDS on localhost) and checks the tables' columns and
rows, the machine record and the PNG files.  No timing is asserted: the
numbers are whatever this machine measured.
"""
from __future__ import annotations

import json
import os
import re
import struct
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "bench"))

from tests.core.narrow.test_narrow_phase_accuracy import FAMILIES  # noqa: E402

pytestmark = pytest.mark.stress

METHODS = ["numpy.roots loop", "companion eigvals (batched)", "Ferrari closed form (vectorised)",
           "seed lecture (absolute coeffs, 1e-6 tol)", "ours (numba, serial kernel)"]
PNGS = ["accuracy_vs_time.png", "accuracy_vs_time_families.png", "scale.png", "node.png"]


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("bench")
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", MPLBACKEND="Agg")
    proc = subprocess.run(
        # the three sections that run inside run_all (the others run their own scripts,
        # each with its own tests): accuracy against time, scale, node latency
        [sys.executable, str(ROOT / "bench" / "run_all.py"), "--quick", "--only", "accuracy",
         "scale", "node", "--out", str(out)],
        cwd=str(ROOT),
        env=env,
        capture_output=True,
        text=True,
        timeout=280,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return out


def tables(text: str) -> list[tuple[list[str], list[list[str]]]]:
    """Every markdown table in ``text`` as (header, rows); checks the separator line."""
    found = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        if (
            lines[i].startswith("|")
            and i + 1 < len(lines)
            and re.fullmatch(r"\|(:?-+:?\|)+", lines[i + 1])
        ):
            cells = lambda s: [c.strip() for c in s.strip().strip("|").split("|")]  # noqa: E731
            header = cells(lines[i])
            sep = cells(lines[i + 1])
            assert len(sep) == len(header) and all(set(c) <= set(":-") and "-" in c for c in sep), (
                lines[i + 1]
            )
            rows = []
            i += 2
            while i < len(lines) and lines[i].startswith("|"):
                row = cells(lines[i])
                assert len(row) == len(header), (header, row)
                rows.append(row)
                i += 1
            found.append((header, rows))
        else:
            i += 1
    return found


def table_with(text: str, first_columns: list[str]):
    for header, rows in tables(text):
        if header[: len(first_columns)] == first_columns:
            return header, rows
    raise AssertionError(f"no table starting with columns {first_columns}")


def number(cell: str) -> float:
    cell = cell.strip("*").replace(",", "")
    if cell in ("inf", "n/a"):
        return float(cell.replace("n/a", "nan"))
    return float(cell)


def test_all_files_written(quick_run):
    for name in ["machine.md", "summary.md", "accuracy_vs_time.md", "scale.md", "node.md",
                 "results.json", *PNGS]:
        assert (quick_run / name).is_file() and (quick_run / name).stat().st_size > 0, name
    res = json.loads((quick_run / "results.json").read_text())
    assert res["quick"] is True and {"machine", "accuracy", "scale", "node"} <= set(res)


def test_pngs_are_valid(quick_run):
    for name in PNGS:
        data = (quick_run / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n", name
        length, kind = struct.unpack(">I4s", data[8:16])
        assert kind == b"IHDR" and length == 13, name
        width, height = struct.unpack(">II", data[16:24])
        assert width >= 200 and height >= 200, (name, width, height)
        assert data[-12:-8] == b"\x00\x00\x00\x00" and data[-8:-4] == b"IEND", name


def test_machine_record(quick_run):
    _, rows = table_with((quick_run / "machine.md").read_text(), ["item", "value"])
    items = {r[0]: r[1] for r in rows}
    for key in ("date", "CPU model", "logical CPUs", "Python", "numpy", "numba", "numba threads"):
        assert items.get(key), key
    assert items["Python"] == sys.version.split()[0]


def test_accuracy_tables(quick_run):
    text = (quick_run / "accuracy_vs_time.md").read_text()
    header, rows = table_with(text, ["method", "ns/pair (mean of families)"])
    assert header == ["method", "ns/pair (mean of families)", "ns/pair (median family)",
                      "x ours serial (mean)", "x ours serial (median family)", "median err (ulp)",
                      "worst finite err (ulp)", "wrong t=0", "contacts > 4 ulp", "missed",
                      "spurious"]
    names = [r[0] for r in rows]
    assert (
        names[:5] == METHODS and len(names) == 6 and names[5].startswith("ours (time_to_collision")
    )
    for r in rows:
        assert number(r[1]) > 0 and number(r[2]) > 0 and number(r[3]) > 0 and number(r[4]) > 0
        for c in r[5:7]:
            assert number(c) >= 0 or c == "n/a"
        assert all(int(c) >= 0 for c in r[7:])
    ours = rows[METHODS.index("ours (numba, serial kernel)")]
    assert number(ours[3]) == 1.0 and number(ours[4]) == 1.0  # the ratios' base

    header, rows = table_with(text, ["family", "numpy.roots loop"])
    assert header[1:] == names
    assert [r[0] for r in rows] == list(FAMILIES) + ["**total**"]
    for r in rows:
        for c in r[1:]:
            m, s = c.strip("*").split(" / ")
            assert int(m) >= 0 and int(s) >= 0

    header, rows = table_with(text, ["family", "method", "ns/pair"])
    assert header == ["family", "method", "ns/pair", "median err (ulp)", "worst err (ulp)",
                      "contacts", "missed", "spurious", "ambiguous (exempt)"]
    assert [(r[0], r[1]) for r in rows] == [(f, m) for f in FAMILIES for m in names]


def test_scale_table(quick_run):
    import scale

    header, rows = table_with((quick_run / "scale.md").read_text(), ["density", "horizon s", "N"])
    assert header[3:6] == ["all-pairs narrow ms", "predict_all_pairs ms", "speed-up"]
    assert (
        "cull rate" in header
        and "peak RSS rise MiB" in header
        and "1-body update ms (median)" in header
    )
    expect = [
        (d, f"{h:g}", str(n))
        for d in scale.DENSITIES
        for h in scale.HORIZONS
        for n in scale.NS_QUICK
    ]
    assert [tuple(r[:3]) for r in rows] == expect
    for r in rows:
        assert number(r[4]) > 0 and 0 < number(r[6]) <= 1
        assert r[-1] in ("yes", "-")  # all-pairs and broad phase agree wherever both ran
        if int(r[2]) <= scale.ALL_PAIRS_MAX_QUICK:
            assert number(r[3]) > 0 and r[-1] == "yes"


def test_node_table(quick_run):
    header, rows = table_with((quick_run / "node.md").read_text(), ["bodies", "input Hz"])
    assert header == ["bodies", "input Hz", "answered/sent", "end-to-end p50 ms",
                      "end-to-end p99 ms", "node p50 ms", "node p99 ms", "candidate pairs",
                      "burst in/s", "burst out/s"]
    assert [r[0] for r in rows] == ["100"]
    r = rows[0]
    assert r[1] != "failed", (quick_run / "node.md").read_text()
    answered, sent = map(int, r[2].split("/"))
    assert sent > 0 and 0 < answered <= sent
    assert number(r[3]) > 0 and number(r[4]) >= number(r[3])


def test_summary(quick_run):
    summary = (quick_run / "summary.md").read_text()
    table_with(summary, ["method", "ns/pair (mean of families)"])
    table_with(summary, ["density (bodies/km^2)", "horizon s"])
    table_with(summary, ["bodies", "input Hz"])
    for png in PNGS:
        assert png in summary
