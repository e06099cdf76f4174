"""Compiled, GIL-free kernels for the contrast enhancement (eq. 1), the straight
sequence search (eq. 2) and the ranking of candidates, behind :mod:`placeloc.seqslam.search`.

In NumPy all three were bound by the GIL on many cores, not by memory: each of their many
small calls holds it to dispatch or index, and 16 threads queue for it. On one H100 host's
16 cores the NumPy enhancement took 0.23 s on one core and 0.21 s on 16; the straight search
scaled 2.1x (``python bench/scaling.py --cores``, the localize kernels' table); the compiled
ones take 0.09 s and 0.03 s, and 0.13 s and 0.04 s. Written as LLVM IR and compiled by
llvmlite like the difference kernels (:mod:`placeloc.seqslam.l1`, which compiles and
caches them), they run without the GIL, one thread per core, and pay no numba start-up.

They do the same floating-point operations in the same order as the NumPy code they
replace (no fast-math: no reassociation, no fused multiply-add), so their output is
bit-identical to it (``tests/test_seqslam_kernels.py`` checks that against the NumPy
reference, ``search.enhance_rows_numpy``, ``search.trajectory_scores_numpy`` and
``search.top_k_numpy``).
"""

from __future__ import annotations

import ctypes
import functools
import struct

import numpy as np

# The variance below which a window counts as flat (its z-score is 0), as in eq. (1)'s code.
FLAT_VARIANCE = 1e-12


def _double(x: float) -> str:
    """An LLVM IR double constant, exact (the hexadecimal form)."""
    return "0x" + struct.pack(">d", x).hex().upper()


# One stretch r0..r1-1 of a row: the window sums from the running sums c1, c2, then mean,
# variance, z-score + shift, rounded to float32. {BOUNDS} sets %lo, %hi and %n (the count).
_ZONE = r"""
define internal void @{NAME}(float* noalias nocapture readonly %x, float* noalias nocapture %out,
                           double* noalias nocapture readonly %c1, double* noalias nocapture readonly %c2,
                           i64 %nr, i64 %R, double %shift, i64 %r0, i64 %r1) alwaysinline {{
entry:
  %empty = icmp sge i64 %r0, %r1
{SETUP}
  br i1 %empty, label %exit, label %loop
loop:
  %r = phi i64 [%r0, %entry], [%rn, %loop]
{BOUNDS}
  %p1h = getelementptr inbounds double, double* %c1, i64 %hi
  %p1l = getelementptr inbounds double, double* %c1, i64 %lo
  %p2h = getelementptr inbounds double, double* %c2, i64 %hi
  %p2l = getelementptr inbounds double, double* %c2, i64 %lo
  %a1h = load double, double* %p1h, align 8
  %a1l = load double, double* %p1l, align 8
  %a2h = load double, double* %p2h, align 8
  %a2l = load double, double* %p2l, align 8
  %s1 = fsub double %a1h, %a1l
  %s2 = fsub double %a2h, %a2l
  %m = fdiv double %s1, %n
  %v0 = fdiv double %s2, %n
  %mm = fmul double %m, %m
  %v = fsub double %v0, %mm
  %ok = fcmp ogt double %v, {FLAT}
  %sd0 = call double @llvm.sqrt.f64(double %v)
  %sd = select i1 %ok, double %sd0, double 1.0
  %px = getelementptr inbounds float, float* %x, i64 %r
  %xf = load float, float* %px, align 4
  %xd = fpext float %xf to double
  %dx = fsub double %xd, %m
  %z0 = fdiv double %dx, %sd
  %z = select i1 %ok, double %z0, double 0.0
  %zs = fadd double %z, %shift
  %zf = fptrunc double %zs to float
  %po = getelementptr inbounds float, float* %out, i64 %r
  store float %zf, float* %po, align 4
  %rn = add nsw i64 %r, 1
  %more = icmp slt i64 %rn, %r1
  br i1 %more, label %loop, label %exit
exit:
  ret void
}}
"""
# The row's ends: the window r-R..r+R clipped to the row, its count per r.
_CLIPPED = dict(NAME="zone", SETUP="", BOUNDS="""\
  %lo0 = sub i64 %r, %R
  %lneg = icmp slt i64 %lo0, 0
  %lo = select i1 %lneg, i64 0, i64 %lo0
  %hi0a = add i64 %r, %R
  %hi0 = add i64 %hi0a, 1
  %hbig = icmp sgt i64 %hi0, %nr
  %hi = select i1 %hbig, i64 %nr, i64 %hi0
  %ni = sub i64 %hi, %lo
  %n = sitofp i64 %ni to double""")
# The interior: no clipping, so the loads are contiguous and LLVM vectorises the loop.
_INTERIOR = dict(NAME="zone_inner", SETUP="""\
  %width0 = shl i64 %R, 1
  %width1 = add i64 %width0, 1
  %n = sitofp i64 %width1 to double""", BOUNDS="""\
  %lo = sub nsw i64 %r, %R
  %hi0 = add nsw i64 %r, %R
  %hi = add nsw i64 %hi0, 1""")

# Per row: running sums of x and x^2 in float64 (c1, c2, a leading 0), then the three
# stretches of r: the clipped left end, the interior, the clipped right end.
_ENHANCE = r"""
declare double @llvm.sqrt.f64(double)

define void @enhance_rows(float* noalias nocapture readonly %x, float* noalias nocapture %out, i64 %n, i64 %nr,
                          i64 %R, double %shift, double* noalias nocapture %c1, double* noalias nocapture %c2) {
entry:
  store double 0.0, double* %c1, align 8
  store double 0.0, double* %c2, align 8
  %rows = icmp sgt i64 %n, 0
  %cols = icmp sgt i64 %nr, 0
  %any = and i1 %rows, %cols
  br i1 %any, label %row, label %exit
row:
  %i = phi i64 [0, %entry], [%in, %row_done]
  %base = mul nsw i64 %i, %nr
  %xr = getelementptr inbounds float, float* %x, i64 %base
  %or = getelementptr inbounds float, float* %out, i64 %base
  br label %sums
sums:
  %k = phi i64 [0, %row], [%kn, %sums]
  %acc1 = phi double [0.0, %row], [%acc1n, %sums]
  %acc2 = phi double [0.0, %row], [%acc2n, %sums]
  %pxk = getelementptr inbounds float, float* %xr, i64 %k
  %xkf = load float, float* %pxk, align 4
  %xk = fpext float %xkf to double
  %acc1n = fadd double %acc1, %xk
  %sq = fmul double %xk, %xk
  %acc2n = fadd double %acc2, %sq
  %kn = add nsw i64 %k, 1
  %pc1 = getelementptr inbounds double, double* %c1, i64 %kn
  %pc2 = getelementptr inbounds double, double* %c2, i64 %kn
  store double %acc1n, double* %pc1, align 8
  store double %acc2n, double* %pc2, align 8
  %kmore = icmp slt i64 %kn, %nr
  br i1 %kmore, label %sums, label %zones
zones:
  %e0 = icmp slt i64 %R, %nr
  %left = select i1 %e0, i64 %R, i64 %nr
  %right0 = sub i64 %nr, %R
  %rsmall = icmp slt i64 %right0, %left
  %right = select i1 %rsmall, i64 %left, i64 %right0
  call void @zone(float* %xr, float* %or, double* %c1, double* %c2, i64 %nr, i64 %R, double %shift, i64 0, i64 %left)
  call void @zone_inner(float* %xr, float* %or, double* %c1, double* %c2, i64 %nr, i64 %R, double %shift, i64 %left, i64 %right)
  call void @zone(float* %xr, float* %or, double* %c1, double* %c2, i64 %nr, i64 %R, double %shift, i64 %right, i64 %nr)
  br label %row_done
row_done:
  %in = add nsw i64 %i, 1
  %imore = icmp slt i64 %in, %n
  br i1 %imore, label %row, label %exit
exit:
  ret void
}
"""

# For each query row q of a..b-1 and each trajectory v: acc[j] = sum_t et[q + t_off[t],
# lo_v + j + traj[v, t]] for j < hi_v - lo_v (the adds in t's order, from 0), then
# s[q - a, lo_v + j] = min(s[q - a, lo_v + j], acc[j]); s starts at +inf.
_TRAJECTORY = r"""
define void @trajectory_rows(float* noalias nocapture readonly %et, float* noalias nocapture %s, float* noalias nocapture %acc,
                             i64 %a, i64 %b, i64 %nr, i64* noalias nocapture readonly %toff, i64 %nt,
                             i64* noalias nocapture readonly %traj, i64* noalias nocapture readonly %lo,
                             i64* noalias nocapture readonly %hi, i64 %nv) {{
entry:
  %rows = icmp slt i64 %a, %b
  br i1 %rows, label %row, label %exit
row:
  %q = phi i64 [%a, %entry], [%qn, %row_done]
  %qa = sub nsw i64 %q, %a
  %sbase = mul nsw i64 %qa, %nr
  %srow = getelementptr inbounds float, float* %s, i64 %sbase
  br label %fill
fill:
  %f = phi i64 [0, %row], [%fn, %fill]
  %pf = getelementptr inbounds float, float* %srow, i64 %f
  store float 0x7FF0000000000000, float* %pf, align 4
  %fn = add nsw i64 %f, 1
  %fmore = icmp slt i64 %fn, %nr
  br i1 %fmore, label %fill, label %vels
vels:
  %v = phi i64 [0, %fill], [%vn, %vel_done]
  %vleft = icmp slt i64 %v, %nv
  br i1 %vleft, label %vel, label %row_done
vel:
  %plo = getelementptr inbounds i64, i64* %lo, i64 %v
  %phi_ = getelementptr inbounds i64, i64* %hi, i64 %v
  %rlo = load i64, i64* %plo, align 8
  %rhi = load i64, i64* %phi_, align 8
  %width = sub nsw i64 %rhi, %rlo
  %some = icmp sgt i64 %width, 0
  br i1 %some, label %zero, label %vel_done
zero:
  %z = phi i64 [0, %vel], [%zn, %zero]
  %pz = getelementptr inbounds float, float* %acc, i64 %z
  store float 0.0, float* %pz, align 4
  %zn = add nsw i64 %z, 1
  %zmore = icmp slt i64 %zn, %width
  br i1 %zmore, label %zero, label %steps
steps:
  %t = phi i64 [0, %zero], [%tn, %step_done]
  %tleft = icmp slt i64 %t, %nt
  br i1 %tleft, label %step, label %fold
step:
  %pt = getelementptr inbounds i64, i64* %toff, i64 %t
  %dt = load i64, i64* %pt, align 8
  %vt0 = mul nsw i64 %v, %nt
  %vt = add nsw i64 %vt0, %t
  %po = getelementptr inbounds i64, i64* %traj, i64 %vt
  %o = load i64, i64* %po, align 8
  %src_row = add nsw i64 %q, %dt
  %src0 = mul nsw i64 %src_row, %nr
  %src1 = add nsw i64 %src0, %rlo
  %src2 = add nsw i64 %src1, %o
  %src = getelementptr inbounds float, float* %et, i64 %src2
  br label %add
add:
  %j = phi i64 [0, %step], [%jn, %add]
  %pa = getelementptr inbounds float, float* %acc, i64 %j
  %ps = getelementptr inbounds float, float* %src, i64 %j
  %va = load float, float* %pa, align 4
  %vs = load float, float* %ps, align 4
  %sum = fadd float %va, %vs
  store float %sum, float* %pa, align 4
  %jn = add nsw i64 %j, 1
  %jmore = icmp slt i64 %jn, %width
  br i1 %jmore, label %add, label %step_done
step_done:
  %tn = add nsw i64 %t, 1
  br label %steps
fold:
  %dst = getelementptr inbounds float, float* %srow, i64 %rlo
  br label %min
min:
  %m = phi i64 [0, %fold], [%mn, %min]
  %pm = getelementptr inbounds float, float* %dst, i64 %m
  %pam = getelementptr inbounds float, float* %acc, i64 %m
  %old = load float, float* %pm, align 4
  %new = load float, float* %pam, align 4
  %lt = fcmp olt float %new, %old
  %un = fcmp uno float %new, %new
  %take = or i1 %lt, %un
  %keep = select i1 %take, float %new, float %old
  store float %keep, float* %pm, align 4
  %mn = add nsw i64 %m, 1
  %mmore = icmp slt i64 %mn, %width
  br i1 %mmore, label %min, label %vel_done
vel_done:
  %vn = add nsw i64 %v, 1
  br label %vels
row_done:
  %qn = add nsw i64 %q, 1
  %qmore = icmp slt i64 %qn, %b
  br i1 %qmore, label %row, label %exit
exit:
  ret void
}}
"""

# Greedy non-maximum suppression per row, as search.top_k_numpy: k times, the first reference of
# the smallest score (stop at +inf), recorded, then its +-w neighbours set to +inf. Each
# row's minima per block of 64 references are kept, so a pick scans the block minima and
# one block, and a suppression refreshes only the blocks it touched, instead of the whole
# row per pick (30 picks a query: the 10 separated and the 20 plain candidates).
_TOP_K = r"""
define internal float @block_min(float* noalias nocapture readonly %row, i64 %j0, i64 %j1) alwaysinline {{
entry:
  %empty = icmp sge i64 %j0, %j1
  br i1 %empty, label %exit, label %loop
loop:
  %j = phi i64 [%j0, %entry], [%jn, %loop]
  %m = phi float [0x7FF0000000000000, %entry], [%mn, %loop]
  %p = getelementptr inbounds float, float* %row, i64 %j
  %v = load float, float* %p, align 4
  %lt = fcmp olt float %v, %m
  %mn = select i1 %lt, float %v, float %m
  %jn = add nsw i64 %j, 1
  %more = icmp slt i64 %jn, %j1
  br i1 %more, label %loop, label %exit
exit:
  %r = phi float [0x7FF0000000000000, %entry], [%mn, %loop]
  ret float %r
}}

; the minima of blocks b0..b1 (inclusive) of 64 references of a row
define internal void @block_mins(float* noalias nocapture readonly %row, float* noalias nocapture %bmin, i64 %nr,
                                 i64 %b0, i64 %b1) alwaysinline {{
entry:
  br label %loop
loop:
  %b = phi i64 [%b0, %entry], [%bn, %loop]
  %j0 = shl i64 %b, 6
  %j1a = add i64 %j0, 64
  %big = icmp sgt i64 %j1a, %nr
  %j1 = select i1 %big, i64 %nr, i64 %j1a
  %m = call float @block_min(float* %row, i64 %j0, i64 %j1)
  %p = getelementptr inbounds float, float* %bmin, i64 %b
  store float %m, float* %p, align 4
  %bn = add nsw i64 %b, 1
  %more = icmp sle i64 %bn, %b1
  br i1 %more, label %loop, label %exit
exit:
  ret void
}}

define void @top_k_rows(float* noalias nocapture %s, i64 %n, i64 %nr, i64 %w, i64 %k, i64* noalias nocapture %best,
                        float* noalias nocapture %scores, float* noalias nocapture %bmin) {{
entry:
  %nb0 = add i64 %nr, 63
  %nb = lshr i64 %nb0, 6
  %go = icmp sgt i64 %n, 0
  %cols = icmp sgt i64 %nr, 0
  %any = and i1 %go, %cols
  br i1 %any, label %row, label %exit
row:
  %i = phi i64 [0, %entry], [%in, %row_done]
  %base = mul nsw i64 %i, %nr
  %r = getelementptr inbounds float, float* %s, i64 %base
  %kbase = mul nsw i64 %i, %k
  %blast = add nsw i64 %nb, -1
  call void @block_mins(float* %r, float* %bmin, i64 %nr, i64 0, i64 %blast)
  br label %picks
picks:
  %kk = phi i64 [0, %row], [%kkn, %suppressed]
  %kleft = icmp slt i64 %kk, %k
  br i1 %kleft, label %find, label %row_done
find:
  %fb = phi i64 [0, %picks], [%fbn, %find]
  %fm = phi float [0x7FF0000000000000, %picks], [%fmn, %find]
  %fi = phi i64 [-1, %picks], [%fin, %find]
  %pfb = getelementptr inbounds float, float* %bmin, i64 %fb
  %vb = load float, float* %pfb, align 4
  %flt = fcmp olt float %vb, %fm
  %fmn = select i1 %flt, float %vb, float %fm
  %fin = select i1 %flt, i64 %fb, i64 %fi
  %fbn = add nsw i64 %fb, 1
  %fmore = icmp slt i64 %fbn, %nb
  br i1 %fmore, label %find, label %found
found:
  %none = icmp slt i64 %fin, 0
  br i1 %none, label %row_done, label %locate_start
locate_start:
  %lj0 = shl i64 %fin, 6
  br label %locate
locate:
  %lj = phi i64 [%lj0, %locate_start], [%ljn, %locate_next]
  %plj = getelementptr inbounds float, float* %r, i64 %lj
  %vlj = load float, float* %plj, align 4
  %hit = fcmp oeq float %vlj, %fmn
  br i1 %hit, label %record, label %locate_next
locate_next:
  %ljn = add nsw i64 %lj, 1
  br label %locate
record:
  %slot = add nsw i64 %kbase, %kk
  %pbest = getelementptr inbounds i64, i64* %best, i64 %slot
  store i64 %lj, i64* %pbest, align 8
  %pscore = getelementptr inbounds float, float* %scores, i64 %slot
  store float %vlj, float* %pscore, align 4
  %lo0 = sub nsw i64 %lj, %w
  %loneg = icmp slt i64 %lo0, 0
  %lo = select i1 %loneg, i64 0, i64 %lo0
  %hi0 = add nsw i64 %lj, %w
  %last = add nsw i64 %nr, -1
  %hibig = icmp sgt i64 %hi0, %last
  %hi = select i1 %hibig, i64 %last, i64 %hi0
  br label %clear
clear:
  %cj = phi i64 [%lo, %record], [%cjn, %clear]
  %pcj = getelementptr inbounds float, float* %r, i64 %cj
  store float 0x7FF0000000000000, float* %pcj, align 4
  %cjn = add nsw i64 %cj, 1
  %cmore = icmp sle i64 %cjn, %hi
  br i1 %cmore, label %clear, label %refresh
refresh:
  %rb0 = lshr i64 %lo, 6
  %rb1 = lshr i64 %hi, 6
  call void @block_mins(float* %r, float* %bmin, i64 %nr, i64 %rb0, i64 %rb1)
  br label %suppressed
suppressed:
  %kkn = add nsw i64 %kk, 1
  br label %picks
row_done:
  %in = add nsw i64 %i, 1
  %imore = icmp slt i64 %in, %n
  br i1 %imore, label %row, label %exit
exit:
  ret void
}}
"""

_P = ctypes.c_void_p
_I = ctypes.c_int64
_ENHANCE_SIGNATURE = ctypes.CFUNCTYPE(None, _P, _P, _I, _I, _I, ctypes.c_double, _P, _P)
_TRAJECTORY_SIGNATURE = ctypes.CFUNCTYPE(None, _P, _P, _P, _I, _I, _I, _P, _I, _P, _P, _P, _I)
_TOP_K_SIGNATURE = ctypes.CFUNCTYPE(None, _P, _I, _I, _I, _I, _P, _P, _P)


@functools.lru_cache(maxsize=1)
def _kernels() -> dict:
    """The three kernels, compiled as one module (or loaded from the cache), once per
    process: every chunk of every call asks for them."""
    from placeloc.seqslam.l1 import compiled_module

    flat = _double(FLAT_VARIANCE)
    source = (_ENHANCE + _ZONE.format(FLAT=flat, **_CLIPPED) + _ZONE.format(FLAT=flat, **_INTERIOR)
              + _TRAJECTORY.format() + _TOP_K.format())
    return compiled_module("seqslam_rows", source, (("enhance_rows", _ENHANCE_SIGNATURE),
                                                    ("trajectory_rows", _TRAJECTORY_SIGNATURE),
                                                    ("top_k_rows", _TOP_K_SIGNATURE)))


def warm_up() -> None:
    """Load the three kernels (compiled, or from the cache) now."""
    _kernels()


def enhance_rows(dt: np.ndarray, window: int, shift: float, out: np.ndarray) -> None:
    """Eq. (1) along each row of ``dt`` (float32, C-contiguous) into ``out`` (same shape):
    per reference ``r`` the z-score of ``dt[q, r]`` over ``r - window .. r + window``
    (clipped at the ends; a window with variance <= :data:`FLAT_VARIANCE` gives 0), plus
    ``shift``. Sums in float64, bit for bit as the NumPy ``search.enhance_rows_numpy``."""
    _check_rows("dt", dt)
    _check_rows("out", out)
    if dt.shape != out.shape:
        raise ValueError(f"shapes differ: {dt.shape} and {out.shape}")
    n, nr = dt.shape
    scratch = np.empty((2, nr + 1), np.float64)
    _kernels()["enhance_rows"](dt.ctypes.data, out.ctypes.data, n, nr, int(window), float(shift),
                      scratch[0].ctypes.data, scratch[1].ctypes.data)


def trajectory_scores(et: np.ndarray, rows: tuple[int, int], t_off: np.ndarray, traj: np.ndarray) -> np.ndarray:
    """``s[q - a, r] = min_V sum_t et[q + t, r + traj[V, t]]`` for ``q`` in ``rows = (a, b)``
    (every ``q + t`` inside ``et``); inf where a trajectory would leave the matrix. Adds in
    the order of ``t_off``, bit for bit as the NumPy ``search.trajectory_scores_numpy``."""
    _check_rows("et", et)
    a, b = rows
    nr = et.shape[1]
    t_off = np.ascontiguousarray(t_off, np.int64)
    traj = np.ascontiguousarray(traj, np.int64)
    if traj.ndim != 2 or traj.shape[1] != len(t_off):
        raise ValueError(f"traj {traj.shape} does not match {len(t_off)} query offsets")
    if b > a and (a + int(t_off.min()) < 0 or b - 1 + int(t_off.max()) >= et.shape[0]):
        raise ValueError(f"rows {a}:{b} with offsets {int(t_off.min())}..{int(t_off.max())} leave the {et.shape[0]} rows")
    lo = np.maximum(0, -traj.min(axis=1)).astype(np.int64)
    hi = np.minimum(nr, nr - traj.max(axis=1)).astype(np.int64)
    s = np.empty((max(0, b - a), nr), np.float32)
    if b <= a or nr == 0:
        return s
    acc = np.empty(nr, np.float32)
    _kernels()["trajectory_rows"](et.ctypes.data, s.ctypes.data, acc.ctypes.data, int(a), int(b), nr, t_off.ctypes.data,
                         len(t_off), traj.ctypes.data, lo.ctypes.data, hi.ctypes.data, len(traj))
    return s


def top_k(s: np.ndarray, window: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Greedy non-maximum suppression per row of ``s`` (C-contiguous float32; destroyed):
    the ``k`` smallest scores at least ``window + 1`` apart (ties: the first reference),
    ``-1`` / inf when none is left; bit for bit as the NumPy ``search.top_k_numpy``."""
    _check_rows("s", s)
    n, nr = s.shape
    best = np.full((n, k), -1, np.int64)
    scores = np.full((n, k), np.inf, np.float32)
    if n and nr and k:
        blocks = np.empty(-(-nr // 64), np.float32)
        _kernels()["top_k_rows"](s.ctypes.data, n, nr, int(window), int(k), best.ctypes.data, scores.ctypes.data, blocks.ctypes.data)
    return best, scores


def _check_rows(name: str, x: np.ndarray) -> None:
    """The kernels read and write rows through raw pointers: C-contiguous 2-D float32 only."""
    if x.dtype != np.float32 or not x.flags.c_contiguous or x.ndim != 2:
        raise ValueError(f"{name} must be a C-contiguous 2-D float32 array")
