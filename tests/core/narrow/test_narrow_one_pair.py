"""The public ``time_to_collision`` is a C builtin (``core/narrow/one_pair_entry.c``,
``core/narrow/one_pair``) answering one pair itself, in front of the Python
general path.

Guarantees proved here:

* One pair given as 1-D vectors -- lists, tuples, 1-D float64 arrays
  (strided views too), any mix of them, with float, int or numpy float
  numbers -- gets bit for bit the answer of the same row in a batch, as a
  numpy.float64 (numpy's type for a 0-d result), in 2-D and 3-D, with
  finite, infinite and zero horizons:
  over a random mix with the hard rows of test_narrow_phase_exact (classes A-D, rows for the
  exact path, constant velocity, span rows) and a hypothesis search.
* A batch of one -- (1, D) arrays and/or (1,) radii or horizon -- gets the
  batch answer as a float64 array of shape (1,), as the general path returns.
* The horizon positional, as the keyword ``horizon`` or left out (inf);
  other keywords and argument counts are the general path's (same answers,
  same errors).
* Bad input: wrong or mismatched vector lengths, non-numeric values and None
  raise an error that names the argument; NaN / inf values, negative radii
  and negative or NaN horizons give NaN, as in a batch.
* The C path really serves these calls (not the general path behind it),
  ``help()`` and ``inspect.signature`` describe the public function, and
  without the built extension the general path answers, with a warning.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from circle_collision_ros.core import time_to_collision
from circle_collision_ros.core import narrow
from circle_collision_ros.core.narrow import batch as narrow_phase
from tests.core.narrow.test_narrow_phase_accuracy import mixed_pairs
from tests.core.narrow.test_narrow_phase_exact import GENS as HARD_GENS
from tests.core.narrow.test_narrow_phase_span import GENS as SPAN_GENS


def _rows_of(P):
    """Batch arrays -> list of one-pair rows (tuples of floats)."""
    n = len(P[3])
    return [tuple(tuple(float(v) for v in x[i]) if np.ndim(x) == 2 else float(x[i]) for x in P)
            for i in range(n)]


def _batch(rows, H):
    arrs = [np.array([r[k] for r in rows], dtype=float) for k in range(8)]
    return time_to_collision(*arrs, horizon=np.asarray(H, dtype=float))


def _forms(row, rng):
    """The same pair as tuples, lists, 1-D arrays, strided 1-D views, and a mix."""
    def strided(x):
        y = np.empty(2 * len(x))
        y[::2] = x
        return y[::2]
    kinds = [lambda x: tuple(x), lambda x: list(x), lambda x: np.array(x, dtype=float), strided]
    yield from ([k(x) if isinstance(x, tuple) else x for x in row] for k in kinds)
    yield [kinds[int(rng.integers(4))](x) if isinstance(x, tuple) else np.float64(x) for x in row]


def _hard_rows(D, rng):
    rows = []
    for g in sorted(HARD_GENS):
        rows += HARD_GENS[g](rng, 25, D)
    for g in sorted(SPAN_GENS):
        rows += SPAN_GENS[g](rng, 4, D)
    rows += _rows_of(mixed_pairs(200, D, 3))
    rows += _rows_of(mixed_pairs(100, D, 4, straight_fraction=1.0))
    return rows


@pytest.mark.parametrize("D", [2, 3])
def test_one_pair_bitwise_batch_on_hard_mix(D):
    rng = np.random.default_rng([17, D])
    rows = _hard_rows(D, rng)
    Hs = rng.choice([math.inf, 10.0, 2.0, 0.0, 1e-9], len(rows))
    batch = _batch(rows, Hs)
    bad = []
    for row, H, want in zip(rows, Hs, batch):
        for form in _forms(row, rng):
            got = time_to_collision(*form, float(H))
            ok = (type(got) is np.float64
                  and (got == want or (math.isnan(got) and math.isnan(want))))
            if not ok:
                bad.append((row, H, want, got, [type(x).__name__ for x in form]))
    assert not bad, f"{len(bad)} mismatches, first: {bad[:3]}"


_num = st.one_of(
    st.floats(-30, 30), st.integers(-20, 20), st.sampled_from([0.0, -0.0, 1e-300, 1e140])
)


@settings(max_examples=300, deadline=None)
@given(D=st.sampled_from([2, 3]), data=st.data(), H=st.one_of(st.just(math.inf), st.floats(0, 50)),
       kind=st.sampled_from(["tuple", "list", "array"]))
def test_one_pair_bitwise_batch_hypothesis(D, data, H, kind):
    vec = st.lists(_num, min_size=D, max_size=D)
    pa, va, aa, pb, vb, ab = (data.draw(vec) for _ in range(6))
    ra, rb = data.draw(st.floats(0, 5)), data.draw(st.floats(0, 5))
    conv = {"tuple": tuple, "list": list, "array": lambda x: np.array(x, dtype=float)}[kind]
    got = time_to_collision(conv(pa), conv(va), conv(aa), ra, conv(pb), conv(vb), conv(ab), rb, H)
    want = time_to_collision(
        *(np.array([x], dtype=float) for x in (pa, va, aa, ra, pb, vb, ab, rb)), horizon=H
    )[0]
    assert type(got) is np.float64 and (got == want or (math.isnan(got) and math.isnan(want)))


def test_batch_shape_scalar_is_a_numpy_float64_on_every_path():
    """Batch shape (): numpy.float64 from the C entry and from the general path
    (a 0-d horizon array, a row for the exact path) alike."""
    row = ([-10.0, 0.0], [1.0, 0.0], [0.0, 0.0], 1.0, [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], 1.0)
    for t in (time_to_collision(*row), time_to_collision(*row, horizon=np.array(20.0)),
              time_to_collision(*(np.array(x) for x in row))):
        assert type(t) is np.float64 and t == 8.0 and t.shape == ()
    touch = ((3.0, 4.0), (-4.0, 3.0), (1.0, -7.0), 5.0, (0.0, 0.0), (0.0, 0.0), (0.0, 0.0), 0.0)
    t = time_to_collision(*touch)  # third-order touch: decided by the exact path
    assert type(t) is np.float64 and t == 0.0


def test_c_entry_serves_one_pair_calls():
    """The calls above are answered by the C path, not by the general path."""
    # built by setup.py (bootstrap, colcon)
    from circle_collision_ros.core.narrow import one_pair_entry

    row = ([-10.0, 0.0], [1.0, 0.0], [0.0, 0.0], 1.0, [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], 1.0)
    assert time_to_collision(*row) == 8.0
    assert type(time_to_collision).__name__ == "builtin_function_or_method"
    assert narrow.time_to_collision is time_to_collision
    for form in _forms(
        tuple(tuple(x) if isinstance(x, list) else x for x in row), np.random.default_rng(0)
    ):
        t = one_pair_entry.c_path(*form, math.inf)
        assert type(t) is np.float64 and t == 8.0
        assert one_pair_entry.c_path(*form) == 8.0  # horizon left out: inf
    one = [np.array([x]) for x in row]
    t = one_pair_entry.c_path(*one, 5.0)
    assert type(t) is np.ndarray and t.shape == (1,) and t[0] == math.inf
    # not for this path: the general path decides (None)
    assert one_pair_entry.c_path([[-10.0, 0.0]], *row[1:], math.inf) is None  # a list of rows
    assert one_pair_entry.c_path(np.zeros((2, 2)), *row[1:], math.inf) is None  # a batch of 2
    assert one_pair_entry.c_path(*row[:3], np.array(1.0), *row[4:], math.inf) is None  # 0-d radius
    assert one_pair_entry.c_path(*row[:3], True, *row[4:], math.inf) is None  # bool
    assert one_pair_entry.c_path(*row[:3], 1.0, *row[4:], np.array(2.0)) is None  # 0-d horizon
    f4 = np.array([-10.0, 0.0], dtype=np.float32)
    assert one_pair_entry.c_path(f4, *row[1:], math.inf) is None  # float32
    touch = ((3.0, 4.0), (-4.0, 3.0), (1.0, -7.0), 5.0, (0.0, 0.0), (0.0, 0.0), (0.0, 0.0), 0.0)
    assert one_pair_entry.c_path(*touch) is None  # left undecided by the kernels: the exact path


@pytest.mark.parametrize("D", [2, 3])
def test_batch_of_one_is_a_shape_1_array_bitwise_the_batch(D):
    """(1, D) vectors and/or (1,) radii / horizon: the general path's result
    shape (1,), bitwise its value, whichever arguments have the batch axis."""
    rng = np.random.default_rng([17, 1, D])
    rows = _hard_rows(D, rng)[::3]
    Hs = rng.choice([math.inf, 10.0, 2.0, 0.0], len(rows))
    want = _batch(rows, Hs)
    for row, H, w in zip(rows, Hs, want):
        full = [np.array([x], dtype=float) for x in row] + [np.array([H])]
        mixed = [
            np.array([x], dtype=float)
            if rng.random() < 0.5
            else (np.array(x) if isinstance(x, tuple) else x)
            for x in row
        ] + [float(H)]
        if not any(
            isinstance(x, np.ndarray) and x.ndim == (2 if isinstance(r, tuple) else 1)
            for x, r in zip(mixed, row)
        ):
            mixed[0] = np.array([row[0]], dtype=float)
        for args in (full, full[:8] + [float(H)], mixed):
            got = time_to_collision(*args)
            assert type(got) is np.ndarray and got.shape == (1,) and got.dtype == np.float64
            assert got.tobytes() == np.array([w]).tobytes(), (row, H, got, w)


def test_horizon_keyword_positional_default_and_other_calls():
    row = ([-10.0, 0.0], [1.0, 0.0], [0.0, 0.0], 1.0, [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], 1.0)
    assert time_to_collision(*row) == 8.0
    assert time_to_collision(*row, 5.0) == math.inf
    assert time_to_collision(*row, horizon=5.0) == math.inf
    assert time_to_collision(*row, horizon=8.0) == 8.0
    # other keywords: the general path, same answers
    names = ("p_a", "v_a", "a_a", "r_a", "p_b", "v_b", "a_b", "r_b")
    kw = dict(zip(names, row))
    t = time_to_collision(**kw, horizon=5.0)
    assert type(t) is np.float64 and t == math.inf
    assert time_to_collision(*row[:4], **dict(zip(names[4:], row[4:]))) == 8.0
    with pytest.raises(TypeError):
        time_to_collision(*row[:7])  # too few: the general path's TypeError
    with pytest.raises(TypeError):
        time_to_collision(*row, 5.0, 6.0)  # too many
    with pytest.raises(TypeError):
        time_to_collision(*row, horizont=5.0)  # misspelt keyword
    with pytest.raises(TypeError):
        time_to_collision(*row, 5.0, horizon=5.0)  # horizon twice


def test_help_and_signature_describe_the_public_function():
    import inspect
    import pydoc

    sig = inspect.signature(time_to_collision)
    assert list(sig.parameters) == ["p_a", "v_a", "a_a", "r_a", "p_b", "v_b", "a_b", "r_b",
                                    "horizon"]
    assert sig.parameters["horizon"].default == math.inf
    assert time_to_collision.__doc__ == inspect.getdoc(narrow_phase.time_to_collision)
    assert time_to_collision.__doc__.startswith("Earliest time at which two")
    assert time_to_collision.__name__ == "time_to_collision"
    assert time_to_collision.__module__ == "circle_collision_ros.core.narrow.batch"
    text = pydoc.render_doc(time_to_collision, renderer=pydoc.plaintext)
    assert "time_to_collision(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b, horizon=inf)" in text
    assert "Earliest time at which two" in text


def test_without_the_extension_the_general_path_answers_with_a_warning():
    """A source tree whose extension was not built: importing the core warns,
    and time_to_collision is the Python general path with the same answers."""
    import subprocess
    import sys

    code = (
        "import sys, warnings\n"
        "sys.modules['circle_collision_ros.core.narrow.one_pair_entry'] = None"
        "  # import fails as if not built\n"
        "with warnings.catch_warnings(record=True) as w:\n"
        "    warnings.simplefilter('always')\n"
        "    from circle_collision_ros.core import time_to_collision as T\n"
        "assert any('one_pair_entry is not built' in str(x.message) for x in w), "
        "[str(x.message) for x in w]\n"
        "assert type(T).__name__ == 'function'\n"
        "t = T([-10.0, 0.0], [1.0, 0.0], [0.0, 0.0], 1.0, "
        "[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], 1.0)\n"
        "print(type(t).__name__, float(t))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=240)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["float64", "8.0"]


Z2 = (0.0, 0.0)
GOOD = ([-10.0, 0.0], [1.0, 0.0], [0.0, 0.0], 1.0, [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], 1.0)


@pytest.mark.parametrize(
    "k, bad, match",
    [(0, [0.0, 0.0, 0.0, 0.0], r"last axis of size 2 or 3; got shapes p_a \(4,\)"),
     (1, [0.0], r"v_a \(1,\)"), (2, [0.0, 0.0, 0.0], r"p_a \(2,\), v_a \(2,\), a_a \(3,\)"),
     (5, [], r"v_b \(0,\)"), (6, 1.0, r"a_b \(\)"), (0, ["a", 0.0], r"p_a is not numeric"),
     (3, "x", r"r_a is not numeric")],
)
@pytest.mark.parametrize("kind", [list, tuple, np.array])
def test_bad_shapes_and_types_raise_naming_the_argument(k, bad, match, kind):
    row = [kind(x) if isinstance(x, list) else x for x in GOOD]
    row[k] = kind(bad) if isinstance(bad, list) else bad
    with pytest.raises(ValueError, match=match):
        time_to_collision(*row)


def test_batch_shapes_that_do_not_broadcast_are_named():
    pa = np.zeros((2, 2))
    with pytest.raises(ValueError, match=r"do not broadcast: p_a \(2,\), .* r_a \(3,\)"):
        time_to_collision(pa, *GOOD[1:3], np.ones(3), *GOOD[4:])


@pytest.mark.parametrize("k", range(9))
def test_none_raises_naming_the_argument(k):
    row = list(GOOD) + [math.inf]
    row[k] = None
    name = ("p_a", "v_a", "a_a", "r_a", "p_b", "v_b", "a_b", "r_b", "horizon")[k]
    with pytest.raises(TypeError, match=f"{name} is None"):
        time_to_collision(*row)


@pytest.mark.parametrize("kind", [list, tuple, np.array])
@pytest.mark.parametrize(
    "k, j, value",
    [(0, 0, math.nan), (1, 1, math.inf), (2, 0, -math.inf), (4, 1, math.nan), (5, 0, math.nan),
     (6, 1, math.inf), (3, None, -1.0), (7, None, -1e-300), (3, None, math.nan), (8, None, -1.0),
     (8, None, math.nan)],
)
def test_invalid_values_give_nan_like_a_batch(kind, k, j, value):
    row = [list(x) if isinstance(x, list) else x for x in GOOD] + [math.inf]
    if j is None:
        row[k] = value
    else:
        row[k][j] = value
    one = time_to_collision(*(kind(x) if isinstance(x, list) else x for x in row))
    batch = time_to_collision(*(np.array([x]) for x in row[:8]), horizon=np.array([row[8]]))
    assert type(one) is np.float64 and math.isnan(one) and math.isnan(batch[0])
