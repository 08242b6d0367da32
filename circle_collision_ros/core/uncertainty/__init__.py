"""Probability of contact under Gaussian uncertainty of the states.

``uncertain_pairs`` gives, per pair, the probability that the two bodies touch
within the horizon with its stated error bound and the earliest plausible
contact time; ``covariance_problem`` is the light input check the pipeline
runs on covariances; ``inflation_radius`` widens the broad phase for them.
Method and guarantees: docs/uncertainty.md.

Parts: ``covariance`` (the input check, numpy only), ``batch`` (the API over
rows), ``pair`` (one pair's evaluation), ``tube`` (the k-sigma tube and the
screen), ``projection`` (the screen's one-direction bound), ``interval`` (the
cheap certified interval of rows left unevaluated), ``walk`` (the plausible-time
walk), ``reentry`` (accelerating pairs' re-entry bounds), ``qmc`` (the sampling
fallbacks), ``entry_rate`` (Rice's entry rate), ``overlap`` (instantaneous
probabilities), ``line_sampling``, ``quadrature``, ``sobol``.

Only ``covariance`` is imported with the package; the names of ``batch`` (and
the numba kernels behind them) load on first use.
"""
from circle_collision_ros.core.uncertainty.covariance import (COV_PSD_RTOL, COV_SYMMETRY_RTOL,
                                                              covariance_problem)

__all__ = ["UncertainPairs", "uncertain_pairs", "deferred_count", "BROAD_PHASE_SIGMAS",
           "TUBE_TAIL", "inflation_radius",
           "covariance_problem", "COV_SYMMETRY_RTOL", "COV_PSD_RTOL", "load_fallback_kernels"]

_FROM_BATCH = frozenset(__all__) - {"covariance_problem", "COV_SYMMETRY_RTOL", "COV_PSD_RTOL"}


def __getattr__(name: str):
    if name in _FROM_BATCH:
        from circle_collision_ros.core.uncertainty import batch

        return getattr(batch, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
