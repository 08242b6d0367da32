"""Many damaged bags through `replay`'s main() in one process (a crash shows as its exit code).

    python -m tests.reliability.replay_worker OUT_DIR SEED COUNT

Writes each case to OUT_DIR/current.mcap (and its name to OUT_DIR/current.txt)
before running it, so a crash (e.g. SIGSEGV inside rclpy) leaves the culprit
behind; prints one JSON line: cases per outcome and any case whose output broke
the contract (an exception escaping main, or an error that is not one line).
"""
from __future__ import annotations

import contextlib
import io
import json
import os
import sys
from pathlib import Path

import numpy as np

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

from circle_collision_ros.recording import replay  # noqa: E402
from circle_collision_ros.recording.bag_recorder import BagRecorder  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "data"
SOURCES = sorted(DATA.glob("*/*.mcap"))
STATES, PREDICTIONS = ("circle_collision_msgs/msg/CircleStateArray",
                       "circle_collision_msgs/msg/CollisionPredictionArray")


def mutate(data: bytes, rng: np.random.Generator) -> tuple[str, bytes]:
    kind = str(rng.choice(["truncate", "flip", "overwrite", "splice", "zero_tail", "garbage"]))
    b = bytearray(data)
    n = len(b)
    if kind == "truncate":
        return kind, bytes(b[: int(rng.integers(0, n))])
    if kind == "flip":
        for _ in range(int(rng.integers(1, 9))):
            k = int(rng.integers(0, n))
            b[k] ^= 1 << int(rng.integers(0, 8))
        return kind, bytes(b)
    if kind == "overwrite":
        k = int(rng.integers(0, n))
        m = int(rng.integers(1, 64))
        b[k:k + m] = rng.integers(0, 256, min(m, n - k), dtype=np.uint8).tobytes()
        return kind, bytes(b)
    if kind == "splice":  # a piece moved elsewhere (e.g. a botched copy)
        i, j = sorted(int(x) for x in rng.integers(0, n, 2))
        k = int(rng.integers(0, n))
        return kind, bytes(b[:k] + b[i:j] + b[k:])
    if kind == "zero_tail":
        k = int(rng.integers(0, n))
        b[k:] = bytes(n - k)
        return kind, bytes(b)
    return kind, rng.integers(0, 256, int(rng.integers(0, 4096)), dtype=np.uint8).tobytes()


def foreign_bag(path: Path, rng: np.random.Generator) -> None:
    """A well-formed MCAP (valid CRCs) whose payloads on our topics are garbage."""
    if path.exists():
        for f in path.iterdir():
            f.unlink()
        path.rmdir()
    with BagRecorder(path) as rec:
        rec.add_topic("/circle_states", STATES)
        rec.add_topic("/collision_predictions", PREDICTIONS)
        t = 10**18
        for _ in range(int(rng.integers(1, 6))):
            t += 1000
            size = int(rng.integers(0, 200))
            head = [b"\x00\x01\x00\x00", b"\x00\x00\x00\x00", b""][int(rng.integers(0, 3))]
            topic = "/circle_states" if rng.random() < 0.5 else "/collision_predictions"
            rec.write(topic, head + rng.integers(0, 256, size, dtype=np.uint8).tobytes(), t)


def main() -> int:
    out, seed, count = Path(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
    rng = np.random.default_rng(seed)
    sources = [p.read_bytes() for p in SOURCES]
    outcomes: dict[str, int] = {}
    broken: list[str] = []
    for case in range(count):
        tolerant = bool(rng.integers(0, 2))
        if rng.random() < 0.15:
            kind, target = "foreign_payloads", out / "foreign"
            foreign_bag(target, rng)
        else:
            kind, data = mutate(sources[int(rng.integers(0, len(sources)))], rng)
            target = out / "current.mcap"
            target.write_bytes(data)
        (out / "current.txt").write_text(f"case {case} {kind} tolerant={tolerant}\n")
        err, std = io.StringIO(), io.StringIO()
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(std):
                code = replay.main([str(target)] + (["--tolerant"] if tolerant else []))
        except BaseException as exc:  # noqa: BLE001 -- the contract is that nothing escapes
            broken.append(f"case {case} {kind}: {exc!r}")
            continue
        lines = err.getvalue().strip().splitlines()
        key = f"{kind}:exit{code}"
        outcomes[key] = outcomes.get(key, 0) + 1
        if code == 2 and (len(lines) != 1 or "Traceback" in err.getvalue()):
            broken.append(f"case {case} {kind}: exit 2 with {len(lines)} stderr lines: {lines[:3]}")
        if code not in (0, 1, 2):
            broken.append(f"case {case} {kind}: exit {code}")
    print(json.dumps({"cases": count, "outcomes": outcomes, "broken": broken[:20]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
