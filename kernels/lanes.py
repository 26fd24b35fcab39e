"""Lane arithmetic: the BRDF code written once for one pixel or for several pixels per thread.

The shading code (``kernels.brdf``, ``kernels.brdf_grad``) is written over a lane scalar
``L`` and a lane 3-vector ``V``, built per scalar type ``F`` and lane count:

    lanes = 1    L = F, V = vec3(F): one pixel per thread, plain Warp builtins
                 (differentiable: Warp's generated adjoint runs on this build). CUDA and
                 the position-gradient path use it.
    lanes = N    L = vector(N, F), V = matrix(3, N, F) (row c: channel c of N pixels):
                 N consecutive pixels of a row per thread, the CPU's build. Warp's CPU
                 code runs one task per thread and LLVM vectorises only within a task
                 (kernels/DESIGN.md): with pixels as lanes every operation is a loop over
                 N lanes that it turns into AVX-512 / AVX2 instructions.

Warp 1.19's ``wp.sqrt``, ``wp.log`` and ``wp.pow`` take scalars only, so the N-lane
build has lane-wise native snippets (``wp.func_native``): plain loops over the lanes
that the C++ compiler vectorises. Warp's CPU compiler runs clang's cc1 without
``-fmath-errno``, so ``sqrtf`` in a loop becomes ``vsqrtps``; ``exp2f`` and ``logf``
have no vector form there (they would stay one libm call per lane), so for float32 the
snippets evaluate them by polynomials fitted for this project (``EXP2_COEFFS``,
``_log_float32``); float64 keeps libm per lane (its kernels serve the gradcheck tests,
not speed).

Every helper takes at least one lane-typed argument: Warp tells the builds' functions
apart by their argument types (they share their Python names).
"""

from functools import cache
from types import SimpleNamespace

import warp as wp

__all__ = ["build_lanes", "CPU_LANES", "EXP2_COEFFS"]

#: Pixels per thread on the CPU: 16 float32 lanes fill one AVX-512 register (a
#: 16-lane prototype ran the forward render 1.79x faster than one pixel per thread
#: even with per-lane libm calls: kernels/DESIGN.md).
CPU_LANES = 16

#: 2^f ~ sum_i c_i f^i on f in [-0.5, 0.5] (degree 6): a least-squares fit of the relative
#: error at 2000 Chebyshev nodes, reweighted towards the largest errors (20 rounds),
#: constant term pinned to 1 (exact 2^0). Evaluated in float32 by Horner's rule its
#: relative error is <= 0.81 ulp of 1 (1.6 * 2^-24, dense grid of 200001 points) against
#: float64 ``2 ** f``: as accurate as libm's exp2f to within one rounding.
EXP2_COEFFS = (
    1.0,
    0.6931472057370575,
    0.24022646890163518,
    0.055503287773059136,
    0.00961848900801768,
    0.0013399931109824956,
    0.0001534579831277032,
)

#: ln 2, the exponent's weight in log(x) = e ln 2 + log(m).
LN2 = 0.6931471805599453


def _lane_loop(lanes: int, first: str, body: str) -> str:
    """C++ snippet: r = first; r.c[q] = body for each lane q (a loop the compiler
    vectorises); ``body`` reads lane q of an argument ``a`` as ``a.c[q]``."""
    return f"auto r = {first};\nfor (int q = 0; q < {lanes}; ++q) {{ r.c[q] = {body}; }}\nreturn r;"


def _exp2_float32(lanes: int) -> str:
    # 2^x = 2^n 2^f with n = rint(x), f = x - n in [-0.5, 0.5]; 2^n built from its
    # exponent bits. Only for x in [-126, 127] (the Fresnel exponent lies in [-12.6, 0]).
    terms = [f"{c!r}f" for c in EXP2_COEFFS]
    poly = terms[-1]
    for t in reversed(terms[:-1]):
        poly = f"({poly}) * f + {t}"
    return (
        "auto r = x;\n"
        f"for (int q = 0; q < {lanes}; ++q) {{\n"
        "    float n = ::rintf(x.c[q]);\n"
        "    float f = x.c[q] - n;\n"
        "    unsigned int bits = (unsigned int)((int)n + 127) << 23;\n"
        f"    r.c[q] = ({poly}) * __builtin_bit_cast(float, bits);\n"
        "}\n"
        "return r;"
    )


def _log_float32(lanes: int) -> str:
    # log x = e ln 2 + log m, x = m 2^e with m in [sqrt(1/2), sqrt(2)); log m =
    # 2 atanh(s), s = (m - 1) / (m + 1), |s| <= 0.1716: the series to s^9 leaves a
    # truncation error 2 s^11 / 11 < 7e-10 absolute (below float32's rounding of log m).
    # For positive normal x only (the fused loss's argument is >= 1).
    return (
        "auto r = x;\n"
        f"for (int q = 0; q < {lanes}; ++q) {{\n"
        "    unsigned int bits = __builtin_bit_cast(unsigned int, x.c[q]);\n"
        "    int e = (int)(bits >> 23) - 127;\n"
        "    float m = __builtin_bit_cast(float, (bits & 0x007fffffu) | 0x3f800000u);\n"
        "    bool high = m > 1.41421356f;\n"
        "    m = high ? m * 0.5f : m;\n"
        "    e = high ? e + 1 : e;\n"
        "    float s = (m - 1.0f) / (m + 1.0f);\n"
        "    float s2 = s * s;\n"
        "    float p = s2 * (0.33333333f + s2 * (0.2f + s2 * (0.14285714f + s2 * 0.11111111f)));\n"
        f"    r.c[q] = (float)e * {LN2!r}f + (2.0f * s + 2.0f * s * p);\n"
        "}\n"
        "return r;"
    )


@cache
def build_lanes(F, lanes: int) -> SimpleNamespace:
    """Lane types and helpers for scalar type ``F`` and ``lanes`` pixels per thread."""
    V3F = wp.types.vector(3, F)
    if lanes == 1:
        return _scalar_lanes(F, V3F)
    return _vector_lanes(F, V3F, lanes)


def _scalar_lanes(F, V3F) -> SimpleNamespace:
    L = F
    V = V3F

    @wp.func
    def mul(a: L, b: L):
        return a * b

    @wp.func
    def div(a: L, b: L):
        return a / b

    @wp.func
    def scale(v: V, s: L):
        return v * s

    @wp.func
    def shrink(v: V, s: L):
        return v / s

    @wp.func
    def dot(a: V, b: V):
        return wp.dot(a, b)

    @wp.func
    def cross(a: V, b: V):
        return wp.cross(a, b)

    @wp.func
    def vec3(x: L, y: L, z: L):
        return V(x, y, z)

    @wp.func
    def from_point(a: V3F, p: V):
        return a - p

    @wp.func
    def tint(v: V, c: V3F):
        return wp.cw_mul(v, c)

    @wp.func
    def sqrt(x: L):
        return wp.sqrt(x)

    @wp.func
    def exp2(x: L):
        return wp.pow(F(2.0), x)

    @wp.func
    def log(x: L):
        return wp.log(x)

    @wp.func
    def select_gt(x: L, y: L, a: L, b: L):
        return wp.where(x > y, a, b)

    @wp.func
    def select_ge(x: L, y: L, a: L, b: L):
        return wp.where(x >= y, a, b)

    return SimpleNamespace(F=F, L=L, V=V, V3F=V3F, lanes=1, iota=F(0.0), **_helpers(locals()))


def _vector_lanes(F, V3F, lanes: int) -> SimpleNamespace:
    L = wp.types.vector(lanes, F)
    V = wp.types.matrix((3, lanes), F)
    f32 = F is wp.float32

    @wp.func
    def mul(a: L, b: L):
        return wp.cw_mul(a, b)

    @wp.func
    def div(a: L, b: L):
        return wp.cw_div(a, b)

    @wp.func
    def vec3(x: L, y: L, z: L):
        return wp.matrix_from_rows(x, y, z)

    @wp.func
    def scale(v: V, s: L):
        return wp.matrix_from_rows(wp.cw_mul(v[0], s), wp.cw_mul(v[1], s), wp.cw_mul(v[2], s))

    @wp.func
    def shrink(v: V, s: L):
        return wp.matrix_from_rows(wp.cw_div(v[0], s), wp.cw_div(v[1], s), wp.cw_div(v[2], s))

    @wp.func
    def dot(a: V, b: V):
        return wp.cw_mul(a[0], b[0]) + wp.cw_mul(a[1], b[1]) + wp.cw_mul(a[2], b[2])

    @wp.func
    def cross(a: V, b: V):
        return wp.matrix_from_rows(
            wp.cw_mul(a[1], b[2]) - wp.cw_mul(a[2], b[1]),
            wp.cw_mul(a[2], b[0]) - wp.cw_mul(a[0], b[2]),
            wp.cw_mul(a[0], b[1]) - wp.cw_mul(a[1], b[0]),
        )

    @wp.func
    def from_point(a: V3F, p: V):
        return wp.matrix_from_rows(L(a[0]) - p[0], L(a[1]) - p[1], L(a[2]) - p[2])

    @wp.func
    def tint(v: V, c: V3F):
        return wp.matrix_from_rows(v[0] * c[0], v[1] * c[1], v[2] * c[2])

    @wp.func_native(_lane_loop(lanes, "x", "wp::sqrt(x.c[q])"))
    def sqrt(x: L) -> L: ...

    @wp.func_native(_exp2_float32(lanes) if f32 else _lane_loop(lanes, "x", "::exp2(x.c[q])"))
    def exp2(x: L) -> L: ...

    @wp.func_native(_log_float32(lanes) if f32 else _lane_loop(lanes, "x", "::log(x.c[q])"))
    def log(x: L) -> L: ...

    @wp.func_native(_lane_loop(lanes, "a", "x.c[q] > y.c[q] ? a.c[q] : b.c[q]"))
    def select_gt(x: L, y: L, a: L, b: L) -> L: ...

    @wp.func_native(_lane_loop(lanes, "a", "x.c[q] >= y.c[q] ? a.c[q] : b.c[q]"))
    def select_ge(x: L, y: L, a: L, b: L) -> L: ...

    return SimpleNamespace(
        F=F, L=L, V=V, V3F=V3F, lanes=lanes, iota=L(*[F(q) for q in range(lanes)]), **_helpers(locals())
    )


_HELPERS = (
    "mul",
    "div",
    "scale",
    "shrink",
    "dot",
    "cross",
    "vec3",
    "from_point",
    "tint",
    "sqrt",
    "exp2",
    "log",
    "select_gt",
    "select_ge",
)


def _helpers(scope: dict) -> dict:
    return {name: scope[name] for name in _HELPERS}
