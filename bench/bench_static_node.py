"""collision_node with a 4,000 x 4,000-cell map: latency at scale, indexing off the path.

    .venv/bin/python bench/bench_static_node.py [--seconds 20] [--quick]

Prints and writes ``bench/results/static_node.md`` (``--quick``: 5 s streams). collision_node
runs as its own process (markers off) as in bench/bench_node.py, whose frame builder
``scene_bytes`` this reuses; a receiver process records each prediction's receipt and rows. All
processes: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a ROS_DOMAIN_ID of their own (locked as the
tests do). World: a 4,000 x 4,000-cell OccupancyGrid (5 cm, 200 m square; border, rooms, long
walls, small blocks: ~200,000 occupied cells) on ``map`` (reliable, transient local); 1,000 discs
(r 0.2-0.5 m, ~1 m/s, small accelerations) in free space, turned back before they reach a wall;
a CircleStateArray of all of them at 30 Hz, stamped at send time.

1. **Scale**: ``--seconds`` of the stream without the map, then with it (a fresh node each).
   Latency per frame = receipt of the first prediction whose stamp covers it - the frame's
   publish call (client side): p50 / p99 / max; target p99 <= 20 ms with the map; the with /
   without ratio. "own answer": frames answered by a prediction of their own stamp (the others
   were coalesced into a later one). Map rows: id_b == "map" rows per prediction (sanity: > 0).
   Node columns: its /diagnostics (rmw receipt -> publish, compute_ms_last, coalesced, missing).
2. **Indexing off the prediction path**: the with-map stream goes on; after 1 s a new map (plus
   a 4 m wall ~3 s ahead of up to 3 bodies with a clear path) is published. Figures: the node's
   ``static_index_ms_last`` (target <= 1 s); publish -> receipt of the first prediction with
   such a body's map row on its new wall (all of them should be in it: one world per
   prediction); latency of the frames sent in that window against all other frames of the run
   (indexing runs on a worker thread: the window's p99 should not jump by the indexing time).
Last, the WARN / ERROR lines of both nodes' logs (rejected maps, input loss, ...).
"""
from __future__ import annotations

import argparse
import array
import fcntl
import json
import os
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

import _common
import machine
from _common import fmt_ms, md_table

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # before rclpy starts (tests do too)
os.environ.pop("ROS_STATIC_PEERS", None)

from bench_node import scene_bytes  # noqa: E402  (also applies the large-scene transport)
import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from nav_msgs.msg import OccupancyGrid  # noqa: E402

from circle_collision_msgs.msg import CircleStateArray, CollisionPredictionArray  # noqa: E402
from circle_collision_ros.pipeline.prediction_codec import decode_prediction_array  # noqa: E402
from circle_collision_ros.pipeline.static_inputs import decode_occupancy_grid  # noqa: E402

CELLS, RES, BLOCK = 4000, 0.05, 10  # cells per side, m per cell, cells per 0.5 m safety block
BODIES, RATE, P99_TARGET_MS, INDEX_TARGET_MS = 1000, 30.0, 20.0, 1000.0
WATCH = 60  # bodies b00000..b00059: the receiver records their map rows' contact points
MAP_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def claim_domain() -> int:
    """A free ROS domain id, locked like the tests and first_run.py do (from 100 down), held
    until this process exits."""
    for domain in range(100, 0, -1):
        lock = os.path.join(tempfile.gettempdir(), f"circle_collision_ros_domain_{domain}.lock")
        fd = os.open(lock, os.O_CREAT | os.O_RDWR, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return domain  # the descriptor stays open: the lock is ours
        except OSError:
            os.close(fd)
    raise SystemExit("no free ROS domain id in 1..100")


def make_map(seed: int = 7) -> np.ndarray:
    """(CELLS, CELLS) bool, row = y: border, 50 rooms, 50 walls, 3,000 small blocks."""
    rng, t = np.random.default_rng(seed), 2  # walls 2 cells (10 cm) thick
    occ = np.zeros((CELLS, CELLS), bool)
    occ[:t] = occ[-t:] = occ[:, :t] = occ[:, -t:] = True
    for _ in range(50):  # rooms, 4 doors each (earlier rooms inside a new one are cleared)
        (w, h), (x, y) = rng.integers(120, 400, 2), rng.integers(40, CELLS - 440, 2)
        dx, dy = rng.integers(t, w - 20 - t), rng.integers(t, h - 20 - t)
        occ[y:y + h, x:x + w] = True
        occ[y + t:y + h - t, x + t:x + w - t] = False
        occ[y:y + h, x + dx:x + dx + 20] = occ[y + dy:y + dy + 20, x:x + w] = False
    for _ in range(50):
        n, (x, y), flat = rng.integers(200, 800), rng.integers(40, CELLS - 840, 2), rng.random()
        occ[y:y + (t if flat < 0.5 else n), x:x + (n if flat < 0.5 else t)] = True
    for (w, h), (x, y) in zip(rng.integers(1, 5, (3000, 2)),
                              rng.integers(0, CELLS - 5, (3000, 2))):
        occ[y:y + h, x:x + w] = True
    return occ


def safe_blocks(occ: np.ndarray) -> np.ndarray:
    """0.5 m blocks in which a disc of radius <= 0.5 m overlaps no occupied cell (the block and
    its 8 neighbours are free)."""
    n = CELLS // BLOCK
    busy = np.pad(occ.reshape(n, BLOCK, n, BLOCK).any(axis=(1, 3)), 1, constant_values=True)
    near = np.zeros((n, n), bool)
    for di in range(3):
        for dj in range(3):
            near |= busy[di:di + n, dj:dj + n]
    return ~near


def map_message(occ: np.ndarray) -> tuple[bytearray, int]:
    """Serialized OccupancyGrid (frame "map", origin 0, 100 = occupied) and where data starts."""
    msg = OccupancyGrid()
    msg.header.frame_id = "map"
    msg.info.resolution, msg.info.width, msg.info.height = RES, CELLS, CELLS
    msg.info.origin.orientation.w = 1.0
    msg.data = array.array("b", (occ.astype(np.int8) * 100).tobytes())
    data = bytearray(serialize_message(msg))
    at = len(data) - occ.size
    got = decode_occupancy_grid(bytes(data))  # the node's decoder takes it, data where we think
    assert got.width == CELLS and np.array_equal(got.data, np.frombuffer(data, np.int8, -1, at))
    return data, at


class Bodies:
    """The discs (the attributes scene_bytes reads: count, radii, p, v, a; z = 0)."""

    def __init__(self, safe: np.ndarray, seed: int = 11) -> None:
        self.rng, self.safe, n = np.random.default_rng(seed), safe, BODIES
        free = np.argwhere(safe)
        pick = free[self.rng.choice(len(free), n, replace=False)]
        self.count, self.radii = n, self.rng.uniform(0.2, 0.5, n)
        self.p, self.v, self.a = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
        self.p[:, 0] = (pick[:, 1] + self.rng.uniform(0, 1, n)) * BLOCK * RES
        self.p[:, 1] = (pick[:, 0] + self.rng.uniform(0, 1, n)) * BLOCK * RES
        self.v[:, :2] = self._vectors(n, 0.7, 1.3)
        self.a[:, :2] = self._vectors(n, 0.0, 0.1)

    def _vectors(self, n: int, lo: float, hi: float) -> np.ndarray:
        ang = self.rng.uniform(0, 2 * np.pi, n)
        return np.c_[np.cos(ang), np.sin(ang)] * self.rng.uniform(lo, hi, (n, 1))

    def is_safe(self, xy: np.ndarray) -> np.ndarray:
        b = np.clip((xy / (BLOCK * RES)).astype(int), 0, CELLS // BLOCK - 1)
        return self.safe[b[..., 1], b[..., 0]]

    def step(self, dt: float) -> None:
        """Move; a disc whose next block is not safe turns back instead (never touches a wall)."""
        new = self.p + dt * (self.v + 0.5 * dt * self.a)
        ok = self.is_safe(new[:, :2])
        self.p[ok] = new[ok]
        self.v[ok] += dt * self.a[ok]
        self.v[~ok] *= -1.0
        self.a[~ok] *= -1.0
        speed = np.linalg.norm(self.v, axis=1, keepdims=True)
        self.v *= np.minimum(1.0, 1.5 / speed)
        redraw = self.rng.random(self.count) < dt / 2.0  # a new small acceleration every ~2 s
        self.a[redraw, :2] = self._vectors(int(redraw.sum()), 0.0, 0.1)


def plan_walls(bodies: Bodies, occ: np.ndarray, most: int = 3) -> list[tuple[int, np.ndarray]]:
    """Up to `most` watched bodies with a clear path to a spot ~3 s ahead: (body, wall as cell
    rows i0:i1, cols j0:j1), a 4 m x 10 cm wall across the body's main direction."""
    out = []
    for k in range(WATCH):
        p, v = bodies.p[k, :2], bodies.v[k, :2]
        if np.linalg.norm(v) < 0.6:
            continue
        path = p + np.outer(np.arange(0.0, 2.6, 0.1), v)
        cx, cy = (p + 3.0 * v) / RES
        ax = int(abs(v[0]) < abs(v[1]))  # 0: wall across x (vertical), 1: across y
        i0, j0 = (int(cy) - 40, int(cx)) if ax == 0 else (int(cy), int(cx) - 40)
        i1, j1 = (i0 + 80, j0 + 2) if ax == 0 else (i0 + 2, j0 + 80)
        if (min(i0, j0) < 60 or max(i1, j1) > CELLS - 60 or not bodies.is_safe(path).all()
                or occ[i0 - 20:i1 + 20, j0 - 20:j1 + 20].any()):
            continue
        out.append((k, np.array([i0, i1, j0, j1])))
        if len(out) == most:
            break
    return out


def on_new_wall(answer: list, walls: dict) -> list[int]:
    """The watched bodies whose map row in this prediction has its contact point on the wall
    added ahead of them (a cell of slack: the float32 resolution)."""
    def on(k, x, y):
        i0, i1, j0, j1 = walls[k]
        return (j0 - 1) * RES <= x <= (j1 + 1) * RES and (i0 - 1) * RES <= y <= (i1 + 1) * RES
    return [int(k) for k, (x, y) in answer[4].items() if int(k) in walls and on(int(k), x, y)]


def receive(out: str) -> int:
    """Receiver process: per prediction [stamp, receipt, rows, map rows, {k: [x, y]} of the
    watched bodies' map rows], written to `out` on SIGINT. The bytes are decoded only then, so
    decoding takes no CPU from the node (2 cores) while it is measured."""
    rclpy.init()
    node = rclpy.create_node("bench_static_receiver")
    got: list = []
    node.create_subscription(CollisionPredictionArray, "collision_predictions",
                             lambda data: got.append((time.time_ns(), data)),
                             QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE),
                             raw=True)
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        rclpy.try_shutdown()
        rows = []
        for now, data in got:
            sec, nsec = struct.unpack_from("<iI", data, 4)
            pred = decode_prediction_array(data).predictions
            watch = {int(r.id_a[1:]): r.contact_point[:2] for r in pred
                     if r.id_b == "map" and int(r.id_a[1:]) < WATCH}
            rows.append([sec * 10**9 + nsec, now, len(pred),
                         sum(r.id_b == "map" for r in pred), watch])
        Path(out).write_text(json.dumps(rows))
    return 0


class Run:
    """One collision_node (its log in a file), the receiver process, and the publishing client."""

    def __init__(self, label: str, params: dict, map_data: bytes | None) -> None:
        self.label, self.log = label, tempfile.NamedTemporaryFile(suffix=".log", delete=False).name
        self.answers_file = tempfile.NamedTemporaryFile(suffix=".json", delete=False).name
        args = [os.path.join(sys.prefix, "lib", "circle_collision_ros", "collision_node"),
                "--ros-args", "--log-level", "warn", "-p", "marker_rate:=0.0"]
        for k, v in params.items():
            args += ["-p", f"{k}:={v}"]
        with open(self.log, "w") as log:
            self.node = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT)
        self.receiver = subprocess.Popen([sys.executable, __file__, "--receive", self.answers_file])
        rclpy.init()
        self.client = rclpy.create_node("bench_static_client")
        self.lock, self.diag, self.sent = threading.Lock(), {}, []  # sent: (stamp, wall) ns
        self.client.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)
        self.states = self.client.create_publisher(
            CircleStateArray, "circle_states", QoSProfile(depth=100,
                                                          reliability=ReliabilityPolicy.RELIABLE))
        self.map = self.client.create_publisher(OccupancyGrid, "map", MAP_QOS)
        if map_data is not None:
            self.map.publish(bytes(map_data))  # transient local: the node gets it when it joins
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.client)
        threading.Thread(target=self.executor.spin, daemon=True).start()
        # Up once it reports: its first start after a change to the core compiles (minutes).
        deadline = time.monotonic() + 900
        while not self.wait_diag("messages", 0, 30):
            if self.node.poll() is not None or time.monotonic() > deadline:
                tail = Path(self.log).read_text(errors="replace").splitlines()[-15:]
                self.close()
                raise SystemExit(f"{label}: collision_node did not come up:\n" + "\n".join(tail))
            print(f"{label}: waiting for collision_node (compiling?)", flush=True)
        while (self.client.count_subscribers("/collision_predictions") == 0
               and self.receiver.poll() is None):
            time.sleep(0.05)
        time.sleep(0.5)

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if "collision prediction" in status.name:
                with self.lock:
                    self.diag = {kv.key: kv.value for kv in status.values}

    def wait_diag(self, key: str, at_least: float, timeout: float) -> dict:
        """The node's diagnostics once `key` >= at_least ({} if not within `timeout` s)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                if float(self.diag.get(key, "-1")) >= at_least:
                    return dict(self.diag)
            time.sleep(0.1)
        return {}

    def stream(self, bodies: Bodies, seconds: float, event=None) -> None:
        """`seconds` of frames at RATE; event = (at s, fn) runs once between two frames."""
        period = 1.0 / RATE
        start = next_send = time.monotonic()
        while time.monotonic() - start < seconds:
            if event and time.monotonic() - start >= event[0]:
                event, run_it = None, event[1]
                run_it()
            if time.monotonic() >= next_send:
                bodies.step(period)
                stamp = time.time_ns()
                data = scene_bytes(bodies, stamp)  # built before the timed publish call
                self.sent.append((stamp, time.time_ns()))
                self.states.publish(data)
                next_send += period
            time.sleep(max(0.0, min(0.002, next_send - time.monotonic())))

    def warm_up(self, bodies: Bodies) -> None:
        """1 s of frames until the node has answered (not measured)."""
        self.stream(bodies, 1.0)
        if not self.wait_diag("predictions_published", 1, 60):
            raise SystemExit(f"{self.label}: no prediction published after the warm-up")
        time.sleep(1.0)
        self.sent.clear()

    def close(self) -> tuple[list, dict, list[str]]:
        """(answers sorted by (stamp, receipt), last diagnostics, WARN/ERROR lines of the log)."""
        time.sleep(2.2)  # /diagnostics comes once a second
        with self.lock:
            diag = dict(self.diag)
        self.receiver.send_signal(signal.SIGINT)
        try:
            self.receiver.wait(timeout=120)  # it decodes first
            answers = json.loads(Path(self.answers_file).read_text())
        except (subprocess.TimeoutExpired, ValueError, OSError):
            self.receiver.kill()
            answers = []
        self.executor.shutdown()
        self.client.destroy_node()
        rclpy.try_shutdown()
        self.node.send_signal(signal.SIGINT)
        try:
            self.node.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.node.kill()
        log = Path(self.log).read_text(errors="replace").splitlines()
        for f in (self.log, self.answers_file):
            Path(f).unlink(missing_ok=True)
        bad = [f"{self.label}: {ln}" for ln in log if "WARN" in ln or "ERROR" in ln]
        return sorted(answers, key=lambda a: (a[0], a[1])), diag, bad


def latencies(sent: list, answers: list) -> tuple[np.ndarray, int]:
    """Per frame: ms from its publish call to the receipt of the first prediction whose stamp
    covers it (NaN: none); and how many frames got a prediction of their own stamp."""
    stamps = np.array([a[0] for a in answers], dtype=np.int64)
    out, own = np.full(len(sent), np.nan), 0
    for n, (stamp, wall) in enumerate(sent):
        k = int(np.searchsorted(stamps, stamp))
        if k < len(answers):
            out[n] = (answers[k][1] - wall) * 1e-6
            own += int(stamps[k] == stamp)
    return out, own


def pct(ms: np.ndarray) -> list[float]:
    ms = ms[~np.isnan(ms)]
    return [float(np.percentile(ms, q)) for q in (50, 99, 100)] if ms.size else [np.nan] * 3


def scale_row(label: str, sent: list, answers: list, diag: dict) -> tuple[list, float, int]:
    """A table row of part 1, its p99 (ms), and the fewest map rows of one prediction."""
    ms, own = latencies(sent, answers)
    maps = np.array([a[3] for a in answers if sent[0][0] <= a[0] <= sent[-1][0]] or [0])
    p50, p99, mx = pct(ms)
    return ([label, len(sent), f"{own} / {int(np.isnan(ms).sum())}", fmt_ms(p50), fmt_ms(p99),
             fmt_ms(mx), f"{maps.mean():.0f} ({maps.min()}-{maps.max()})"]
            + [diag.get(k, "?") for k in ("latency_ms_p50", "latency_ms_p99", "compute_ms_last",
                                          "inputs_coalesced", "inputs_missing")],
            p99, int(maps.min()))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--quick", action="store_true", help="5 s streams")
    ap.add_argument("--out", default=str(_common.HERE / "results"), help="results directory")
    ap.add_argument("--receive", help=argparse.SUPPRESS)  # internal: the receiver process
    opts = ap.parse_args()
    if opts.receive:
        return receive(opts.receive)  # domain id and discovery range inherited from the parent
    os.environ["ROS_DOMAIN_ID"] = str(claim_domain())
    seconds, t0, info = (5.0 if opts.quick else opts.seconds), time.monotonic(), machine.collect()
    occ = make_map()
    safe = safe_blocks(occ)
    base, data_at = map_message(occ)
    print(f"map: {int(occ.sum()):,} occupied cells, built in {time.monotonic() - t0:.1f} s; "
          f"ROS_DOMAIN_ID {os.environ['ROS_DOMAIN_ID']}", flush=True)

    run = Run("without map", {}, None)  # 1a: the stream alone
    try:
        bodies = Bodies(safe.copy())
        run.warm_up(bodies)
        run.stream(bodies, seconds)
    finally:
        answers, diag, warnings = run.close()
    off_row, off_p99, _ = scale_row("1,000 bodies, no map", run.sent, answers, diag)

    run, walls, t_pub = Run("with map", {"map_topic": "map"}, base), [], 0  # 1b and 2
    try:
        first = run.wait_diag("static_world_version", 1, 120)
        bodies = Bodies(safe.copy())
        run.warm_up(bodies)
        run.stream(bodies, seconds)
        n_steady = len(run.sent)

        def publish_new_map() -> None:
            nonlocal walls, t_pub
            walls = plan_walls(bodies, occ)
            new = bytearray(base)
            cells = np.frombuffer(new, np.int8, occ.size, data_at).reshape(CELLS, CELLS)
            for _, (i0, i1, j0, j1) in walls:
                cells[i0:i1, j0:j1] = 100
                bodies.safe[max(0, i0 // BLOCK - 1):i1 // BLOCK + 2,
                            max(0, j0 // BLOCK - 1):j1 // BLOCK + 2] = False  # they turn too
            t_pub = time.time_ns()
            run.map.publish(bytes(new))

        run.stream(bodies, 7.0, (1.0, publish_new_map))
    finally:
        answers, diag, bad = run.close()
    warnings += bad
    on_row, on_p99, min_rows = scale_row("1,000 bodies, 4,000^2 map", run.sent[:n_steady],
                                         answers, diag)

    watched = dict(walls)
    seen = next(((a[1], on_new_wall(a, watched)) for a in sorted(answers, key=lambda a: a[1])
                 if a[1] >= t_pub and on_new_wall(a, watched)), None)
    index_ms = float(diag.get("static_index_ms_last", "nan"))
    ms, _ = latencies(run.sent, answers)
    wall_ns = np.array([w for _, w in run.sent])
    end = seen[0] if seen else t_pub + index_ms * 1e6
    inside = (wall_ns >= t_pub) & (wall_ns <= end)
    win, rest = pct(ms[inside]), pct(ms[~inside])
    met = lambda ok: "met" if ok else "NOT met"  # noqa: E731
    header = ["run", "frames sent", "own answer / unanswered", "p50 ms", "p99 ms", "max ms",
              "map rows per prediction, mean (min-max)", "node p50 ms", "node p99 ms",
              "node compute_ms_last", "coalesced", "missing"]
    found = (f"{fmt_ms((seen[0] - t_pub) * 1e-6)} ms; watched bodies on their new wall in it: "
             f"{len(seen[1])} of {len(watched)}") if seen else "NEVER (no such prediction)"
    window = md_table(["frames", "count", "p50 ms", "p99 ms", "max ms"], [
        ["sent from the publish to the first prediction with the new walls", int(inside.sum()),
         *map(fmt_ms, win)],
        ["all other frames of the with-map run", int((~inside).sum()), *map(fmt_ms, rest)]])
    log = "\n".join(f"    {ln}" for ln in warnings[:20]) or "none"
    text = f"""# collision_node with a {CELLS:,} x {CELLS:,}-cell map: latency and indexing

`bench/bench_static_node.py{' --quick' if opts.quick else ''}`: {BODIES:,} bodies, \
CircleStateArray at {RATE:.0f} Hz, {seconds:g} s per stream, markers off; map of \
{int(occ.sum()):,} occupied 5 cm cells. Latency: the frame's publish call to the receipt of the \
first prediction covering it (module docstring). Machine: \
{machine.one_line(machine.finish(info, time.monotonic() - t0, {}))}.

## 1. Scale

{md_table(header, [off_row, on_row], "l" + "r" * 11)}
- p99 with the map {fmt_ms(on_p99)} ms (target <= {P99_TARGET_MS:g} ms: \
{met(on_p99 <= P99_TARGET_MS)}); with / without {on_p99 / off_p99:.2f} x
- map rows in every prediction: {'yes' if min_rows > 0 else 'NO'}; first map indexed in \
{first.get('static_index_ms_last', '?')} ms

## 2. A new map while the stream runs

- {len(walls)} walls added ahead of {', '.join(f'b{k:05d}' for k in watched) or '(none)'}; \
static_world_version {diag.get('static_world_version', '?')}, static_inputs_rejected \
{diag.get('static_inputs_rejected', '?')}
- static_index_ms_last {fmt_ms(index_ms)} ms (target <= {INDEX_TARGET_MS:g} ms: \
{met(index_ms <= INDEX_TARGET_MS)})
- publish -> first prediction with the new walls: {found}

{window}
- window p99 - rest p99 = {win[1] - rest[1]:+.1f} ms; indexing took {fmt_ms(index_ms)} ms

## Node log (WARN / ERROR)

{log}

Wall time {time.monotonic() - t0:.0f} s.
"""
    print(text)
    out = Path(opts.out) / "static_node.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    print(f"written: {out.relative_to(_common.ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
