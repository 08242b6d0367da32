"""The one-pair entry of ``time_to_collision``: a C extension over cfuncs.

Issue 17 asks for one pair from Python in at most 0.8 us (pooltool's jitted
``ball_ball_collision_time``).  Measured in one run (bench/bench_core.py,
``--one-pair``): calling the numba dispatcher directly with the pair's 15
floats already costs ~2x a trivial jitted call (~0.6 us idle), 9 arguments
as tuples ~3x, 1-D arrays ~3.4x; with the Python wrapper and the result
on top no numba entry gets under 0.8 us.  So ``_one_pair.c`` reads the
sequences with the CPython API and calls the certified kernels
(``narrow_phase._certified_pair2/3``: fast or straight path, then the
robust solver -- the code the batch runs on a row) through numba ``cfunc``
addresses; it builds with setup.py (``pip install -e .``, colcon), and
scripts/bootstrap.sh rebuilds it when the C source changes.

Rows the kernels leave undecided, and every input the C entry does not take
(other types or shapes, which the general path converts or rejects with its
message), go through the general path: the answers are those of the batch
entry, bit for bit (tests/core/test_narrow_one_pair.py).  Without the
extension (a source tree that was not built) the one-pair calls take the
general path, with a warning once.
"""
from __future__ import annotations

import warnings
from typing import Callable

from numba import cfunc, types

from circle_collision_ros.core.narrow_phase import _certified_pair2, _certified_pair3

_SIG = types.float64(types.CPointer(types.float64))


@cfunc(_SIG, cache=True, error_model="numpy")
def _kernel2(x):
    """``_certified_pair2`` on x[0..15): p_a v_a a_a r_a p_b v_b a_b r_b H."""
    return _certified_pair2(x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10],
                            x[11], x[12], x[13], x[14])


@cfunc(_SIG, cache=True, error_model="numpy")
def _kernel3(x):
    """``_certified_pair3`` on x[0..21): p_a v_a a_a r_a p_b v_b a_b r_b H."""
    return _certified_pair3(x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10],
                            x[11], x[12], x[13], x[14], x[15], x[16], x[17], x[18], x[19], x[20])


def _none(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b, horizon):
    """Stand-in without the extension: always the general path."""
    return None


def load_one_pair() -> Callable:
    """The C entry with its kernels installed (or the stand-in, with a warning)."""
    try:
        from circle_collision_ros.core import _one_pair
    except ImportError as exc:  # a source tree whose extension was not built
        warnings.warn(f"circle_collision_ros.core._one_pair is not built ({exc}); one-pair calls of "
                      "time_to_collision take the general path (~10x slower). Build it with "
                      "scripts/bootstrap.sh, pip install -e . or colcon build.", RuntimeWarning,
                      stacklevel=3)
        return _none
    _one_pair.set_kernels(_kernel2.address, _kernel3.address)
    return _one_pair.ttc
