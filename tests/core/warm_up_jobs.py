"""Compile jobs for tests/core/test_warm_up.py: each appends "<job> <dims> start/end" lines to
the file named by $WARM_UP_TEST_LOG; "left" and "right" each wait for the other to start
(exit 4 after 60 s without it: they were not run side by side); "broken" exits 3."""
from __future__ import annotations

import os
import sys
import time

from circle_collision_ros.core.warm_up import Job, main

_MODULE = "tests.core.warm_up_jobs"


def _job(name: str):
    def run(dimensions: int, horizon: float) -> None:
        with open(os.environ["WARM_UP_TEST_LOG"], "a") as log:
            log.write(f"{name} {dimensions} start {time.monotonic()}\n")
        if name == "broken":
            raise SystemExit(3)
        sibling = {"left": "right", "right": "left"}.get(name)
        deadline = time.monotonic() + 60.0
        while sibling and f"{sibling} {dimensions} start" not in _read():
            if time.monotonic() > deadline:
                raise SystemExit(4)
            time.sleep(0.01)
        with open(os.environ["WARM_UP_TEST_LOG"], "a") as log:
            log.write(f"{name} {dimensions} end {time.monotonic()}\n")
    return run


def _read() -> str:
    with open(os.environ["WARM_UP_TEST_LOG"]) as log:
        return log.read()


JOBS = {
    "base": Job(_job("base"), (), _MODULE),
    "left": Job(_job("left"), ("base",), _MODULE),
    "right": Job(_job("right"), ("base",), _MODULE),
    "top": Job(_job("top"), ("left", "right"), _MODULE),
    "broken": Job(_job("broken"), ("base",), _MODULE),
}

if __name__ == "__main__":
    sys.exit(main(jobs=JOBS))
