"""A scene's prediction as published: rows, message objects, or CDR bytes.

One column builder (`ScenePrediction.columns`) feeds the row view and message
builder (service, markers, tests) and the compiled CDR encoder. The node's
publications (contacts, then the probable uncertain pairs: every case but
report_all_pairs rows and non-finite contacts) take a one-pass encoder from the
scene's rows instead (prediction_codec.encode_contact_rows, joined to the uncertain rows
by the same `_uncertain_join`); tests/pipeline/test_prediction_codec.py proves its bytes equal
the columns path's.

Guarantee: nothing published is NaN. Contacts carry finite times and details;
NO_CONTACT entries carry time +inf and zeros elsewhere, as the message
definition documents.

Reporting rule: a pair is listed iff its mean contact lies within the horizon
(the exact path, unchanged), or it has an uncertain body and its
collision_probability >= probability_threshold (a pair the budget deferred:
probability + bound, the top of its interval; then NO_CONTACT if the mean
paths miss). Rows of exact pairs carry probability 1.0, bound 0.0 and
plausible time = time_to_collision (NO_CONTACT rows of report_all_pairs: 0.0,
0.0, +inf). Order: contacts by (time, id_a, id_b) as the scene keeps them;
then uncertain NO_CONTACT rows by (plausible time, id_a, id_b); then contacts
with static geometry by (time, body id), id_b the obstacle's name; then the
report_all_pairs rest in id order.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator
from concurrent.futures import Executor
from dataclasses import dataclass, replace
from functools import cached_property
from typing import NamedTuple

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Vector3
from std_msgs.msg import Header

from circle_collision_msgs.msg import CollisionPrediction, CollisionPredictionArray
from circle_collision_ros.core.scene import (SceneContacts, SceneSnapshot, SceneUncertainty,
                                            complete_uncertainty)
from circle_collision_ros.pipeline.prediction_codec import (
    encode_contact_rows,
    encode_prediction_array,
)
from circle_collision_ros.pipeline.static_scene import StaticRows

_NS_PER_S = 1_000_000_000


class ReportAll:
    """`report_all_pairs` lists every pair only up to this many bodies (N^2/2 messages)."""

    MAX_BODIES = 100


def split_ns(ns: int) -> tuple[int, int]:
    """(sec, nanosec) of a time in ns, as builtin_interfaces/Time holds it."""
    return divmod(ns, _NS_PER_S)


class PredictionRow(NamedTuple):
    """One CollisionPrediction entry (point and normal always 3-D, z = 0 for circles)."""

    id_a: str
    id_b: str
    status: int
    time_to_collision: float  # s from the header stamp
    contact_time: tuple[int, int]  # (sec, nanosec)
    contact_point: tuple[float, float, float]
    normal: tuple[float, float, float]
    closing_speed: float
    collision_probability: float
    collision_probability_bound: float
    plausible_time_to_collision: float  # s from the header stamp; +inf if never within the horizon


@dataclass(frozen=True)
class PredictionColumns:
    """The entries of one CollisionPredictionArray, column-wise, in publication order."""

    id_a: list[str]
    id_b: list[str]
    status: np.ndarray  # (K,) uint8
    ttc: np.ndarray  # (K,) float64
    contact_ns: np.ndarray  # (K,) int64 (0 for NO_CONTACT)
    point: np.ndarray  # (K, 3)
    normal: np.ndarray  # (K, 3)
    closing_speed: np.ndarray  # (K,)
    probability: np.ndarray  # (K,) float64
    probability_bound: np.ndarray  # (K,) float64
    plausible_ttc: np.ndarray  # (K,) float64, s

    def __len__(self) -> int:
        return len(self.id_a)


@dataclass(frozen=True)
class ScenePrediction:
    """What one prediction found: the scene's contacts, and its states frozen at that moment."""

    contacts: SceneContacts
    capture: object  # core.scene._Capture: the snapshot is propagated only when asked for
    horizon: float
    frame_id: str
    report_all_pairs: bool
    uncertainty: SceneUncertainty | None = None
    probability_threshold: float = 1.0
    #: contacts with static geometry (pipeline.static_scene.static_rows), or None
    static: StaticRows | None = None

    @property
    def deferred(self) -> bool:
        """Whether some uncertain row was deferred (``completed`` has work to do)."""
        return self.uncertainty is not None and self.uncertainty.pending is not None

    def completed(self, executor: Executor | None = None, parts: int = 1,
                  pause: Callable[[], None] | None = None) -> ScenePrediction:
        """This prediction with every deferred uncertain row fully evaluated
        (``core.scene.complete_uncertainty``, with its `executor`, `parts` and `pause`): the
        same contacts, snapshot and stamp, and bit for bit what the same scene predicts with
        ``uncertain_pair_budget`` 0.  Listed by the reporting rule of fully evaluated rows.
        Self when nothing was deferred."""
        if not self.deferred:
            return self
        return replace(self, uncertainty=complete_uncertainty(self.uncertainty, executor, parts,
                                                              pause))

    @property
    def snapshot(self) -> SceneSnapshot:
        """All bodies propagated to the reference time, ordered by id (markers)."""
        return self.capture.snapshot()

    @property
    def reference_ns(self) -> int:
        return self.contacts.reference_ns

    @property
    def stamp(self) -> tuple[int, int]:
        return split_ns(self.contacts.reference_ns)

    @cached_property
    def columns(self) -> PredictionColumns:
        """Contacts sorted by (time, id_a, id_b) as the scene keeps them; with
        report_all_pairs (and at most ReportAll.MAX_BODIES bodies) every other
        pair follows as NO_CONTACT in id order."""
        c = self.contacts
        k = self._finite_rows
        n = len(c) if isinstance(k, slice) else k.size
        d = c.point.shape[1]
        point, normal = np.zeros((n, 3)), np.zeros((n, 3))
        point[:, :d], normal[:, :d] = c.point[k], c.normal[k]
        status = np.where(
            c.overlapping[k], CollisionPrediction.OVERLAPPING, CollisionPrediction.CONTACT
        ).astype(np.uint8)
        id_a, id_b = c.id_a[k].tolist(), c.id_b[k].tolist()
        ttc = c.ttc[k]
        parts = {"status": [status], "ttc": [ttc], "contact_ns": [c.contact_ns[k]],
                 "point": [point], "normal": [normal], "closing": [c.closing_speed[k]],
                 "probability": [np.ones(n)], "bound": [np.zeros(n)], "plausible": [ttc]}

        def no_contact_rows(a: list, b: list, probability, bound, plausible) -> None:
            """Append NO_CONTACT rows (time +inf, zero details) with these probability fields."""
            nonlocal id_a, id_b
            m = len(a)
            id_a, id_b = id_a + a, id_b + b
            for name, value in (("status", np.full(m, CollisionPrediction.NO_CONTACT, np.uint8)),
                                ("ttc", np.full(m, np.inf)), ("contact_ns", np.zeros(m, np.int64)),
                                ("point", np.zeros((m, 3))), ("normal", np.zeros((m, 3))),
                                ("closing", np.zeros(m)), ("probability", probability),
                                ("bound", bound), ("plausible", plausible)):
                parts[name].append(value)

        u = self.uncertainty
        if u is not None and len(u):
            found, e = self._uncertain_join
            has = found >= 0
            parts["probability"][0][has] = u.probability[found[has]]
            parts["bound"][0][has] = u.probability_bound[found[has]]
            parts["plausible"][0] = plausible = ttc.copy()
            plausible[has] = u.plausible_ttc[found[has]]
            no_contact_rows(u.id_a[e].tolist(), u.id_b[e].tolist(), u.probability[e],
                            u.probability_bound[e], u.plausible_ttc[e])
        st = self.static
        if st is not None and len(st):
            m = len(st)
            id_a, id_b = id_a + st.id_a, id_b + st.id_b
            for name, value in (("status", np.where(st.overlapping,
                                                    CollisionPrediction.OVERLAPPING,
                                                    CollisionPrediction.CONTACT).astype(np.uint8)),
                                ("ttc", st.ttc), ("contact_ns", st.contact_ns),
                                ("point", st.point), ("normal", st.normal),
                                ("closing", st.closing_speed), ("probability", np.ones(m)),
                                ("bound", np.zeros(m)), ("plausible", st.ttc)):
                parts[name].append(value)
        if self._report_all_rows:
            ids = self.capture.ids()
            rank = {b: r for r, b in enumerate(ids)}
            pairs = set(zip(map(rank.__getitem__, id_a), map(rank.__getitem__, id_b)))
            rest = [
                (a, b)
                for a in range(len(ids))
                for b in range(a + 1, len(ids))
                if (a, b) not in pairs
            ]
            m = len(rest)
            no_contact_rows([ids[a] for a, _ in rest], [ids[b] for _, b in rest], np.zeros(m),
                            np.zeros(m), np.full(m, np.inf))
        col = {
            name: np.concatenate(values) if len(values) > 1 else values[0]
            for name, values in parts.items()
        }
        f64 = lambda x: np.ascontiguousarray(x, dtype=np.float64)  # noqa: E731
        return PredictionColumns(id_a, id_b, col["status"], f64(col["ttc"]),
                                 np.ascontiguousarray(col["contact_ns"], dtype=np.int64),
                                 col["point"], col["normal"], f64(col["closing"]),
                                 f64(col["probability"]), f64(col["bound"]), f64(col["plausible"]))

    @cached_property
    def _uncertain_join(self) -> tuple[np.ndarray, np.ndarray]:
        """(found, extra): for each published contact row, its row in `uncertainty` (-1: none);
        the uncertainty rows published after the contacts (uncertain pairs whose mean paths miss
        within the horizon, listed when probable), in publication order."""
        c, u = self.contacts, self.uncertainty
        k = self._finite_rows
        if u.matched is c and u.contact_rows is not None:  # the scene matched the pairs
            found = np.full(len(c), -1, dtype=np.int64)
            paired = np.flatnonzero(u.contact_rows >= 0)
            found[u.contact_rows[paired]] = paired
            found = found[k]
        else:
            row = {pair: j for j, pair in enumerate(zip(u.id_a.tolist(), u.id_b.tolist()))}
            found = np.array(
                [row.get(pair, -1) for pair in zip(c.id_a[k].tolist(), c.id_b[k].tolist())],
                dtype=np.int64,
            )
        extra = np.ones(len(u), dtype=bool)
        extra[found[found >= 0]] = False
        # a deferred row states an interval: listed when it reaches the threshold, since its
        # probability may lie anywhere in it
        reach = u.probability if u.deferred_rows is None else np.where(
            u.deferred_rows, u.probability + u.probability_bound, u.probability)
        extra &= (
            (reach >= self.probability_threshold)
            & np.isfinite(u.probability)
            & np.isfinite(u.probability_bound)
        )
        e = np.flatnonzero(extra)
        # by (plausible time, id_a, id_b): the rows are in (id_a, id_b) order (SceneUncertainty),
        # so a stable sort on the time alone (no NaN here: a row with a finite probability has
        # a time or +inf; -0.0 and 0.0 tie, as they compare equal)
        return found, e[np.argsort(u.plausible_ttc[e], kind="stable")]

    @property
    def _report_all_rows(self) -> bool:
        """Whether report_all_pairs appends NO_CONTACT rows for the other pairs."""
        return self.report_all_pairs and len(self.capture) <= ReportAll.MAX_BODIES

    @cached_property
    def _finite_rows(self):
        """The contacts' rows with finite values (slice(None): all of them)."""
        c = self.contacts
        # The scene reports only finite contacts with finite details; this mask is the
        # last line of defence behind the "never publishes NaN" guarantee.
        if all(np.isfinite(x).all() for x in (c.ttc, c.closing_speed, c.point, c.normal)):
            return slice(None)  # the common case, without per-row reductions
        finite = (
            np.isfinite(c.ttc)
            & np.isfinite(c.closing_speed)
            & np.isfinite(c.point).all(axis=1)
            & np.isfinite(c.normal).all(axis=1)
        )
        return np.flatnonzero(finite)

    def rows(self) -> Iterator[PredictionRow]:
        """The entries one by one, in publication order (see `columns`)."""
        c = self.columns
        sec, nanosec = np.divmod(c.contact_ns, _NS_PER_S)
        for a, b, status, ttc, s, ns, p, n, cs, pr, pb, pt in zip(c.id_a, c.id_b, c.status.tolist(),
                                                                  c.ttc.tolist(), sec.tolist(),
                                                                  nanosec.tolist(),
                                                                  c.point.tolist(),
                                                                  c.normal.tolist(),
                                                                  c.closing_speed.tolist(),
                                                                  c.probability.tolist(),
                                                                  c.probability_bound.tolist(),
                                                                  c.plausible_ttc.tolist()):
            yield PredictionRow(a, b, status, ttc, (s, ns), tuple(p), tuple(n), cs, pr, pb, pt)

    def to_message(self) -> CollisionPredictionArray:
        """As a message object (service responses, tests)."""
        predictions = [
            CollisionPrediction(
                id_a=r.id_a,
                id_b=r.id_b,
                status=r.status,
                time_to_collision=r.time_to_collision,
                contact_time=Time(sec=r.contact_time[0], nanosec=r.contact_time[1]),
                contact_point=Point(
                    x=r.contact_point[0], y=r.contact_point[1], z=r.contact_point[2]
                ),
                normal=Vector3(x=r.normal[0], y=r.normal[1], z=r.normal[2]),
                closing_speed=r.closing_speed,
                collision_probability=r.collision_probability,
                collision_probability_bound=r.collision_probability_bound,
                plausible_time_to_collision=r.plausible_time_to_collision,
            )
            for r in self.rows()
        ]
        sec, nanosec = self.stamp
        return CollisionPredictionArray(
            header=Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=self.frame_id),
            horizon=float(self.horizon),
            predictions=predictions,
        )

    def to_cdr(self, *, uncertainty: bool = True) -> bytes:
        """As serialized bytes, without building message objects (the node's path).

        uncertainty=False: the layout before the probability fields (replay of old recordings).
        """
        c, u = self.contacts, self.uncertainty
        no_static = self.static is None or len(self.static) == 0
        if uncertainty and not self._report_all_rows and c.id_utf8 is not None and no_static:
            # The node's cases in one compiled pass, bytes equal to the general path's
            # (tests/pipeline/test_prediction_codec.py): no columns built, no id strings touched.
            uncertain = u is not None and len(u) > 0
            # uncertain rows join only when their ids lie in the contacts' blob and no contact
            # row was dropped (then the columns path below)
            if not uncertain or (
                u.id_utf8 is not None
                and u.id_utf8[0].base is c.id_utf8[0].base
                and isinstance(self._finite_rows, slice)
            ):
                joined = None
                if uncertain:
                    found, extra = self._uncertain_join
                    joined = (found, u.probability, u.probability_bound, u.plausible_ttc, extra,
                              u.id_utf8)
                data = encode_contact_rows(self.stamp, self.frame_id, float(self.horizon), c,
                                           CollisionPrediction.CONTACT,
                                           CollisionPrediction.OVERLAPPING, joined,
                                           CollisionPrediction.NO_CONTACT)
                if data is not None:
                    return data
        columns = self.columns
        # No contact row dropped and none appended: the scene's encoded ids fit the columns.
        same_rows = isinstance(self._finite_rows, slice) and len(columns) == len(c)
        return encode_prediction_array(self.stamp, self.frame_id, float(self.horizon), columns,
                                       c.id_utf8 if same_rows else None, uncertainty=uncertainty)
