"""What a Scene returns: merge outcomes, contacts, uncertain pairs, snapshots."""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np

__all__ = ["MergeResult", "SceneContacts", "SceneUncertainty", "DeferredInputs", "SceneSnapshot"]


class MergeResult(NamedTuple):
    """Row indices (into the merged arrays) by outcome."""

    accepted: np.ndarray        # states stored
    not_newer: np.ndarray       # states not newer than the body's state or its removal
    full: np.ndarray            # new ids refused: max_bodies reached
    removed: np.ndarray         # removals that deleted a body
    removal_ignored: np.ndarray  # removals of unknown ids or older than the body's state


@dataclass(frozen=True)
class SceneContacts:
    """Reported pairs at ``reference_ns``, soonest first (arrays are read-only).

    id_a, id_b : body ids (id_a sorts first; gathered on first use).  ttc : s from
    reference_ns.  contact_ns : absolute contact time, ns.  overlapping : (K,) bool.
    point, normal : (K, D) m and unit.  closing_speed : (K,) m/s.
    """

    reference_ns: int
    #: the scene's ids by slot as published (the scene copies before it changes them)
    #: and each row's two slots: id_a / id_b are gathered from them when first read --
    #: the node's path encodes from id_utf8 and never reads them
    slot_ids: np.ndarray
    slot_a: np.ndarray
    slot_b: np.ndarray
    ttc: np.ndarray
    contact_ns: np.ndarray
    overlapping: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    closing_speed: np.ndarray
    #: The ids as UTF-8 for encoders: ``(blob, start_a, len_a, start_b, len_b)``,
    #: row k's id_a is ``blob[start_a[k]:start_a[k] + len_a[k]]`` (None: ids not all str).
    id_utf8: tuple | None = None

    @cached_property
    def id_a(self) -> np.ndarray:
        return self.slot_ids[self.slot_a]

    @cached_property
    def id_b(self) -> np.ndarray:
        return self.slot_ids[self.slot_b]

    def __len__(self) -> int:
        return int(self.ttc.shape[0])


@dataclass(frozen=True)
class SceneUncertainty:
    """Pairs with an uncertain body that may touch within ``[R, R + H]``, evaluated at ``R``.

    Every pair with at least one uncertain body (non-zero covariance) that the broad phase,
    with radii inflated by ``core.uncertainty.inflation_radius``, cannot rule out, plus every
    such pair with a mean contact; each evaluated by ``core.uncertainty.uncertain_pairs`` on
    the states and covariances propagated to its pair time t_p (``Sigma' = M Sigma M^T``;
    t_p = R for a tracker array, within ``Scene.UNCERTAIN_LAG_NS`` before R otherwise, see
    ``Scene.uncertain_pairs``). Arrays (K,): id_a (sorts first), id_b, probability (of
    contact within [t_p, t_p + H]), probability_bound, plausible_ttc (s from R, +inf if
    never).  Rows are in (id_a, id_b) order.  Pairs of two exact bodies are never listed
    (the exact path answers them).
    """

    reference_ns: int
    id_a: np.ndarray
    id_b: np.ndarray
    probability: np.ndarray
    probability_bound: np.ndarray
    plausible_ttc: np.ndarray
    #: (K,) bool: rows the budget (``max_evaluated``) left without the full evaluation; their
    #: probability and bound are a cheap certified interval's (core.uncertainty.interval).
    #: None: no row was deferred
    deferred_rows: np.ndarray | None = None
    #: (K,) int64: each row's row in `matched` (the contacts given to uncertain_pairs) for the
    #: same pair, -1 if none; None when no contacts were given
    contact_rows: np.ndarray | None = None
    matched: SceneContacts | None = None
    #: The ids as UTF-8 for encoders, as SceneContacts.id_utf8 (None: ids not all str).
    id_utf8: tuple | None = None
    #: The deferred rows' inputs (None when no row was deferred): core.scene.complete_uncertainty
    pending: DeferredInputs | None = None

    def __len__(self) -> int:
        return int(self.probability.shape[0])

    @property
    def deferred(self) -> int:
        """How many rows the budget deferred (``deferred_rows``)."""
        return 0 if self.deferred_rows is None else int(np.count_nonzero(self.deferred_rows))


@dataclass(frozen=True)
class DeferredInputs:
    """The inputs of a SceneUncertainty's deferred rows, kept so that their full evaluation
    can run later, off the prediction path (``core.scene.complete_uncertainty``).

    rows : (k,) int64, the deferred rows' indices.  a, b : each body's state at the pair time
    t_p, ``(p, v, a, radius, covariance)`` with shapes (m, D), (m, D), (m, D), (m,),
    (m, 2D, 2D), of which the deferred rows are ``pick`` (k,): the arrays the scene evaluated,
    kept as they are so that the prediction path copies nothing.  first : (k,) s from t_p,
    where each row's screening tube may first reach the ball (the screen's outcome, which the
    full evaluation need not repeat).  lag : (k,) s, R - t_p.  horizon : s; threshold,
    tolerance: those of the call that deferred them.
    """

    rows: np.ndarray
    a: tuple
    b: tuple
    pick: np.ndarray
    first: np.ndarray
    lag: np.ndarray
    horizon: float
    threshold: float
    tolerance: float


@dataclass(frozen=True)
class SceneSnapshot:
    """All bodies propagated to ``reference_ns``, ordered by id; arrays (N, D) and (N,)."""

    reference_ns: int
    ids: list
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    radii: np.ndarray
