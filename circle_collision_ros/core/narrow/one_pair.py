"""The public ``time_to_collision``: a C builtin in front of the batch entry.

One pair from Python should cost about what a jitted one-pair function costs
(pooltool's ``ball_ball_collision_time`` is the yardstick).  Calling the numba
dispatcher directly with the pair's floats, as tuples or as 1-D arrays, and
a Python function in front of a C entry (its frame, the keyword
``horizon``, the second call) each cost a multiple of that
(``bench/bench_core.py --one-pair`` prints the figures).  So
``time_to_collision`` *is* a C function (``one_pair_entry.c``, vectorcall):
it reads one pair's sequences with the CPython API and calls the certified
kernels (``batch.certified_pair2/3``: fast or straight path, then the robust
solver -- the code the batch runs on a row) through numba ``cfunc``
addresses.  It builds with setup.py (``pip install -e .``, colcon);
scripts/bootstrap.sh rebuilds it when the C source changes.

Every call it does not answer itself -- other types or shapes (which the
general path converts or rejects with its message), other keywords, and rows
the kernels leave undecided -- goes unchanged to the general path, the
Python ``time_to_collision`` of ``batch`` whose docstring and signature the
builtin carries (``help``, ``inspect.signature``): the answers are those of
the batch entry, bit for bit (tests/core/narrow/test_narrow_one_pair.py).
The cfuncs are loaded from numba's cache at the first one-pair call, not at
import.  Without the extension (a source tree that was not built)
``time_to_collision`` is the general path, with a warning at import.
"""
from __future__ import annotations

import importlib.util
import inspect
import math
import warnings
from typing import Callable

from numba import cfunc, types

from circle_collision_ros.core.narrow import batch
from circle_collision_ros.core.narrow.batch import certified_pair2, certified_pair3

_SIG = types.float64(types.CPointer(types.float64))


def _kernel2(x):
    """``certified_pair2`` on x[0..15): p_a v_a a_a r_a p_b v_b a_b r_b H."""
    return certified_pair2(x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10],
                            x[11], x[12], x[13], x[14])


def _kernel3(x):
    """``certified_pair3`` on x[0..21): p_a v_a a_a r_a p_b v_b a_b r_b H."""
    return certified_pair3(x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10],
                            x[11], x[12], x[13], x[14], x[15], x[16], x[17], x[18], x[19], x[20])


_compiled: list = []  # the cfunc objects: their machine code lives as long as they do


def _install_kernels() -> None:
    """Compile the cfuncs (numba's on-disk cache) and hand their addresses to the C entry."""
    from circle_collision_ros.core.narrow import one_pair_entry

    if not _compiled:
        _compiled.extend(
            cfunc(_SIG, cache=True, error_model="numpy")(k) for k in (_kernel2, _kernel3)
        )
    one_pair_entry.set_kernels(_compiled[0].address, _compiled[1].address)


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
        from circle_collision_ros.core.narrow import one_pair_entry
    except ImportError as exc:  # a source tree whose extension was not built
        # Python words a missing submodule of a package still initialising as "most likely
        # a circular import": name the real cause when the file is not there
        found = importlib.util.find_spec("circle_collision_ros.core.narrow.one_pair_entry")
        why = str(exc) if found else "no compiled module in the source tree"
        warnings.warn(
            f"circle_collision_ros.core.narrow.one_pair_entry is not built ({why}); "
            "one-pair calls of "
            f"{general.__name__} take the slower general path. Build it with "
            "scripts/bootstrap.sh, pip install -e . or colcon build.",
            RuntimeWarning,
            stacklevel=2,
        )
        return general
    if general.__name__ != "time_to_collision":  # the builtin's name is fixed in one_pair_entry.c
        raise ValueError(f"public_entry: expected time_to_collision, got {general.__name__}")
    doc = f"{general.__name__}{_text_signature(general)}\n--\n\n{inspect.getdoc(general)}"
    return one_pair_entry.make_entry(general, _install_kernels, doc, general.__module__)


# The public name: answers one pair itself and calls the batch entry for everything else.
time_to_collision = public_entry(batch.time_to_collision)
