"""Error-free transformations and double-double (dd) helpers for numba kernels.

A dd value is a pair ``(hi, lo)`` of float64 with ``|lo| <= ulp(hi)/2``; it
carries ~106 significant bits.  These helpers are only used where float64
would cancel catastrophically: forming relative coordinates (``p_a - p_b`` at
map/UTM magnitudes), and the final residual ``|g(t)|^2 - R^2`` near a root.

Why these are safe (references: Dekker 1971; Ogita, Rump & Oishi 2005):

* ``two_sum`` is exact for any finite float64 pair under round-to-nearest
  (Knuth), no branch on magnitudes needed.
* ``two_prod`` uses a hardware fused multiply-add (``llvm.fma.f64``): the
  rounding error of ``a*b`` is exactly ``fma(a, b, -a*b)`` unless the
  product under/overflows, which needs |inputs| beyond ~1e150 (documented
  input range of the narrow phase).  LLVM falls back to a correctly rounded
  libm ``fma`` on CPUs without the instruction, so results never change.
* numba compiles without ``fastmath``, so LLVM never reassociates these
  sequences (reassociation would silently turn the error terms into 0).
"""
from __future__ import annotations

import math
import struct
from fractions import Fraction

from llvmlite import ir
from numba import config, njit, types
from numba.extending import intrinsic


if config.DISABLE_JIT:  # pure-Python debugging mode: exact rational FMA

    def _fma(a, b, c):
        return float(Fraction(a) * Fraction(b) + Fraction(c))

else:

    @intrinsic
    def _fma(typingctx, a, b, c):  # pragma: no cover - compiled
        """Fused multiply-add ``a*b + c`` with a single rounding."""
        sig = types.float64(types.float64, types.float64, types.float64)

        def codegen(context, builder, signature, args):
            return builder.fma(args[0], args[1], args[2])

        return sig, codegen


_I64 = ir.IntType(64)

if config.DISABLE_JIT:  # pure-Python debugging mode

    def exponent(x):
        """Biased exponent field (0..2047) of a float64."""
        return (struct.unpack("<q", struct.pack("<d", x))[0] >> 52) & 0x7FF

    def pow2(e):
        """The float64 with exponent field e (1..2046) and zero mantissa: 2^(e - 1023)."""
        return struct.unpack("<d", struct.pack("<q", e << 52))[0]

else:

    @intrinsic
    def exponent(typingctx, x):  # pragma: no cover - compiled
        """Biased exponent field (0..2047) of a float64 (bit operations only,
        so a loop using it still vectorises)."""
        sig = types.int64(types.float64)

        def codegen(context, builder, signature, args):
            bits = builder.bitcast(args[0], _I64)
            return builder.and_(builder.lshr(bits, ir.Constant(_I64, 52)), ir.Constant(_I64, 0x7FF))

        return sig, codegen

    @intrinsic
    def pow2(typingctx, e):  # pragma: no cover - compiled
        """The float64 with exponent field e (1..2046) and zero mantissa: 2^(e - 1023)."""
        sig = types.float64(types.int64)

        def codegen(context, builder, signature, args):
            return builder.bitcast(builder.shl(args[0], ir.Constant(_I64, 52)), ir.DoubleType())

        return sig, codegen


if config.DISABLE_JIT:  # pure-Python debugging mode

    def next_down(x):
        """The float64 below a finite x > 0 (bit pattern - 1; 0 for the
        smallest subnormal): ``nextafter(x, 0)`` without a libm call."""
        return struct.unpack(
            "<d", struct.pack("<q", struct.unpack("<q", struct.pack("<d", x))[0] - 1)
        )[0]

    def next_up(x):
        """The float64 above a finite x >= 0 (bit pattern + 1): ``nextafter(x, inf)``."""
        return struct.unpack(
            "<d", struct.pack("<q", struct.unpack("<q", struct.pack("<d", x))[0] + 1)
        )[0]

else:

    @intrinsic
    def next_down(typingctx, x):  # pragma: no cover - compiled
        """The float64 below a finite x > 0 (bit pattern - 1; 0 for the
        smallest subnormal): ``nextafter(x, 0)`` without a libm call, so a
        loop using it still vectorises.  Meaningless for other x."""
        sig = types.float64(types.float64)

        def codegen(context, builder, signature, args):
            bits = builder.bitcast(args[0], _I64)
            return builder.bitcast(builder.sub(bits, ir.Constant(_I64, 1)), ir.DoubleType())

        return sig, codegen

    @intrinsic
    def next_up(typingctx, x):  # pragma: no cover - compiled
        """The float64 above a finite x >= 0 (bit pattern + 1): ``nextafter(x, inf)``."""
        sig = types.float64(types.float64)

        def codegen(context, builder, signature, args):
            bits = builder.bitcast(args[0], _I64)
            return builder.bitcast(builder.add(bits, ir.Constant(_I64, 1)), ir.DoubleType())

        return sig, codegen


@njit(cache=True, error_model="numpy", inline="always")
def pow2_scales(m: float):
    """Powers of two (s1, s2) with ``m * s1 * s2`` in [2, 4) for a finite
    m > 0.  For m = 0, s2 = 1.0 (everything is 0 anyway); for m = inf (a
    relative state that overflowed: inputs out of range) and NaN, s2 = NaN, so
    the scaled state is NaN and no answer is made up from it.

    Multiplying by them (s1 first) is exact for every value <= m that does
    not underflow: s1 = 2^600 lifts a tiny m (< 2^-300, subnormal included)
    into the normal range, s2 = 2^(1024 - e) for the exponent e of m * s1.
    Branch-free (selects and bit operations)."""
    s1 = 4.149515568880993e180 if m < 4.909093465297727e-91 else 1.0  # 2^600, 2^-300
    s2 = pow2(2047 - exponent(m * s1))
    s2 = s2 if m > 0.0 else 1.0
    return s1, (s2 if m < math.inf else math.nan)


@njit(cache=True, error_model="numpy", inline="always")
def two_sum(a: float, b: float):
    """Exact ``a + b = s + e`` (Knuth's branch-free TwoSum)."""
    s = a + b
    bb = s - a
    e = (a - (s - bb)) + (b - bb)
    return s, e


@njit(cache=True, error_model="numpy", inline="always")
def fast_two_sum(a: float, b: float):
    """Exact ``a + b = s + e``; requires ``|a| >= |b|`` or ``a == 0``."""
    s = a + b
    e = b - (s - a)
    return s, e


@njit(cache=True, error_model="numpy", inline="always")
def two_prod(a: float, b: float):
    """Exact ``a * b = p + e`` via FMA."""
    p = a * b
    e = _fma(a, b, -p)
    return p, e


@njit(cache=True, error_model="numpy", inline="always")
def dd_add(ah: float, al: float, bh: float, bl: float):
    """Accurate dd + dd (the IEEE-style variant, relative error ~2u^2).

    The cheaper "sloppy" add is NOT used: it loses all accuracy when the two
    operands nearly cancel, which is exactly the situation near a contact
    (``dp + t*dv`` with ``|dp| >> R``).
    """
    s, e = two_sum(ah, bh)
    t, f = two_sum(al, bl)
    e += t
    s, e = fast_two_sum(s, e)
    e += f
    return fast_two_sum(s, e)


@njit(cache=True, error_model="numpy", inline="always")
def dd_mul(ah: float, al: float, bh: float, bl: float):
    """dd * dd, relative error ~4u^2 (the lo*lo term is below that)."""
    p, e = two_prod(ah, bh)
    e += ah * bl + al * bh
    return fast_two_sum(p, e)


@njit(cache=True, error_model="numpy", inline="always")
def dd_sqr(ah: float, al: float):
    """dd squared."""
    p, e = two_prod(ah, ah)
    e += 2.0 * ah * al
    return fast_two_sum(p, e)
