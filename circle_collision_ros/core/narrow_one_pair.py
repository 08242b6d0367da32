"""The public ``time_to_collision``: a C builtin in front of the general path.

Issue 17 asks for one pair from Python in at most 0.8 us (pooltool's jitted
``ball_ball_collision_time``).  Measured in one run (bench/bench_core.py,
``--one-pair``): calling the numba dispatcher directly with the pair's 15
floats already costs ~2x a trivial jitted call (~0.6 us idle), 9 arguments
as tuples ~3x, 1-D arrays ~3.4x; and a Python function in front of a C entry
(its frame, the keyword ``horizon``, the second call) cost ~0.3 us of the
~1.1 us per call.  So ``time_to_collision`` *is* a C function (``_one_pair.c``,
vectorcall): it reads one pair's sequences with the CPython API and calls the
certified kernels (``narrow_phase._certified_pair2/3``: fast or straight
path, then the robust solver -- the code the batch runs on a row) through
numba ``cfunc`` addresses.  It builds with setup.py (``pip install -e .``,
colcon); scripts/bootstrap.sh rebuilds it when the C source changes.

Every call it does not answer itself -- other types or shapes (which the
general path converts or rejects with its message), other keywords, and rows
the kernels leave undecided -- goes unchanged to the general path, the
Python ``time_to_collision`` of ``narrow_phase`` whose docstring and
signature the builtin carries (``help``, ``inspect.signature``): the answers
are those of the batch entry, bit for bit (tests/core/test_narrow_one_pair.py).
The cfuncs are compiled (from numba's cache: ~0.1 s) at the first one-pair
call, not at import.  Without the extension (a source tree that was not
built) ``time_to_collision`` is the general path, with a warning at import.
"""
from __future__ import annotations

import inspect
import math
import warnings
from typing import Callable

from numba import cfunc, types

from circle_collision_ros.core.narrow_phase import _certified_pair2, _certified_pair3

_SIG = types.float64(types.CPointer(types.float64))


def _kernel2(x):
    """``_certified_pair2`` on x[0..15): p_a v_a a_a r_a p_b v_b a_b r_b H."""
    return _certified_pair2(x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10],
                            x[11], x[12], x[13], x[14])


def _kernel3(x):
    """``_certified_pair3`` on x[0..21): p_a v_a a_a r_a p_b v_b a_b r_b H."""
    return _certified_pair3(x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10],
                            x[11], x[12], x[13], x[14], x[15], x[16], x[17], x[18], x[19], x[20])


_compiled: list = []  # the cfunc objects: their machine code lives as long as they do


def _install_kernels() -> None:
    """Compile the cfuncs (numba's on-disk cache) and hand their addresses to the C entry."""
    from circle_collision_ros.core import _one_pair

    if not _compiled:
        _compiled.extend(cfunc(_SIG, cache=True, error_model="numpy")(k) for k in (_kernel2, _kernel3))
    _one_pair.set_kernels(_compiled[0].address, _compiled[1].address)


def _text_signature(general: Callable) -> str:
    """general's parameters as CPython's __text_signature__ (what
    inspect.signature reads from a builtin): defaults as expressions it can
    evaluate (math.inf, not inf)."""
    parts = []
    for p in inspect.signature(general).parameters.values():
        if p.default is inspect.Parameter.empty:
            parts.append(p.name)
        elif p.default == math.inf:
            parts.append(f"{p.name}=math.inf")
        else:
            parts.append(f"{p.name}={p.default!r}")
    return f"({', '.join(parts)})"


def public_entry(general: Callable) -> Callable:
    """The builtin answering one pair itself and calling ``general`` (same
    arguments) for everything else; ``general`` itself, with a warning,
    without the extension."""
    try:
        from circle_collision_ros.core import _one_pair
    except ImportError as exc:  # a source tree whose extension was not built
        warnings.warn(f"circle_collision_ros.core._one_pair is not built ({exc}); one-pair calls of "
                      f"{general.__name__} take the general path (~10x slower). Build it with "
                      "scripts/bootstrap.sh, pip install -e . or colcon build.", RuntimeWarning,
                      stacklevel=2)
        return general
    if general.__name__ != "time_to_collision":  # the builtin's name is fixed in _one_pair.c
        raise ValueError(f"public_entry: expected time_to_collision, got {general.__name__}")
    doc = f"{general.__name__}{_text_signature(general)}\n--\n\n{inspect.getdoc(general)}"
    return _one_pair.make_entry(general, _install_kernels, doc, general.__module__)
