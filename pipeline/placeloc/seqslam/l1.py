"""Mean absolute difference kernels behind ``comparisons.mean_abs_difference``.

The uint8 kernel is SeqSLAM's hot loop (3576 x 3576 x 2048 byte differences for the
benchmark). Both kernels are a few lines of LLVM IR compiled for this CPU by llvmlite
(numba's code generator, used here without numba) the first time a difference block is
computed: about 0.1 s for both on a quiet machine, after which the machine code is cached on disk (in a private
folder, with a digest keyed by a per-user secret) and loads in 4 ms.
numba itself cost every ``localize`` process about 0.7 s before its first kernel ran (its
import, then the registries its first call loads, which import ``scipy.linalg``): a fifth
of the whole benchmark run.

- uint8: on CPUs with AVX2 the x86 sum-of-absolute-differences instruction (``vpsadbw``,
  32 byte pairs per instruction) is called directly, because LLVM's own vectoriser turns
  the plain loop into 8-byte ``psadbw`` steps (measured: 2.5x slower). Elsewhere the
  plain loop is compiled, which LLVM vectorises for the CPU at hand. Sums are exact
  integers either way.
- float32: the plain loop with reassociation allowed (``fadd fast``), so it vectorises.

Loops are tiled so that a block of ``b`` rows stays in cache while every ``a`` row streams
past it once. The calls go through ctypes, which releases the GIL: one Python thread per
core runs its share of the tiles.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import hashlib
import hmac
import os
import stat
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

# Rows of ``b`` per tile: 48 x 2 KB rows (64x32 thumbnails) stay in a core's L2 cache.
_TILE = 48
# Per-pair sums are 32-bit: 255 * d must fit.
MAX_UINT8_LENGTH = (2**31 - 1) // 255

# sum_k |a[k] - b[k]| by a plain loop, for uint8 (exact, 32-bit) and float32 (any order).
_PAIR_LOOP = r"""
define internal {ACC} @{NAME}({T}* noalias nocapture readonly %a, {T}* noalias nocapture readonly %b, i64 %d) alwaysinline {{
entry:
  %empty = icmp eq i64 %d, 0
  br i1 %empty, label %exit, label %loop
loop:
  %k = phi i64 [0, %entry], [%k1, %loop]
  %acc = phi {ACC} [{ZERO}, %entry], [%acc1, %loop]
  %pa = getelementptr inbounds {T}, {T}* %a, i64 %k
  %pb = getelementptr inbounds {T}, {T}* %b, i64 %k
  %va = load {T}, {T}* %pa, align {ALIGN}
  %vb = load {T}, {T}* %pb, align {ALIGN}
{ABS_DIFF}
  %acc1 = {ADD} {ACC} %acc, %ad
  %k1 = add nuw i64 %k, 1
  %more = icmp ult i64 %k1, %d
  br i1 %more, label %loop, label %exit
exit:
  %r = phi {ACC} [{ZERO}, %entry], [%acc1, %loop]
  ret {ACC} %r
}}
"""

_SAD_SCALAR = "declare i32 @llvm.abs.i32(i32, i1)\n" + _PAIR_LOOP.format(
    NAME="sad_scalar", T="i8", ACC="i32", ZERO="0", ALIGN=1, ADD="add nuw nsw", ABS_DIFF="""\
  %xa = zext i8 %va to i32
  %xb = zext i8 %vb to i32
  %diff = sub nsw i32 %xa, %xb
  %ad = call i32 @llvm.abs.i32(i32 %diff, i1 true)""")

_ABS_FLOAT = "declare float @llvm.fabs.f32(float)\n" + _PAIR_LOOP.format(
    NAME="l1f", T="float", ACC="float", ZERO="0.0", ALIGN=4, ADD="fadd fast", ABS_DIFF="""\
  %diff = fsub fast float %va, %vb
  %ad = call fast float @llvm.fabs.f32(float %diff)""")

# 32-byte blocks through vpsadbw, the last d % 32 bytes through the scalar loop.
_SAD_AVX2 = r"""
declare <4 x i64> @llvm.x86.avx2.psad.bw(<32 x i8>, <32 x i8>)
declare i64 @llvm.vector.reduce.add.v4i64(<4 x i64>)

define internal i32 @sad(i8* noalias nocapture readonly %a, i8* noalias nocapture readonly %b, i64 %d) alwaysinline {
entry:
  %nb = lshr i64 %d, 5
  %none = icmp eq i64 %nb, 0
  br i1 %none, label %blocks_done, label %block
block:
  %k = phi i64 [0, %entry], [%k1, %block]
  %acc = phi <4 x i64> [zeroinitializer, %entry], [%acc1, %block]
  %off = shl i64 %k, 5
  %pa = getelementptr inbounds i8, i8* %a, i64 %off
  %pb = getelementptr inbounds i8, i8* %b, i64 %off
  %qa = bitcast i8* %pa to <32 x i8>*
  %qb = bitcast i8* %pb to <32 x i8>*
  %va = load <32 x i8>, <32 x i8>* %qa, align 1
  %vb = load <32 x i8>, <32 x i8>* %qb, align 1
  %ps = call <4 x i64> @llvm.x86.avx2.psad.bw(<32 x i8> %va, <32 x i8> %vb)
  %acc1 = add <4 x i64> %acc, %ps
  %k1 = add nuw i64 %k, 1
  %more = icmp ult i64 %k1, %nb
  br i1 %more, label %block, label %blocks_done
blocks_done:
  %accf = phi <4 x i64> [zeroinitializer, %entry], [%acc1, %block]
  %sum64 = call i64 @llvm.vector.reduce.add.v4i64(<4 x i64> %accf)
  %sum = trunc i64 %sum64 to i32
  %done = shl i64 %nb, 5
  %rest = sub i64 %d, %done
  %ta = getelementptr inbounds i8, i8* %a, i64 %done
  %tb = getelementptr inbounds i8, i8* %b, i64 %done
  %tail = call i32 @sad_scalar(i8* %ta, i8* %tb, i64 %rest)
  %r = add nuw nsw i32 %sum, %tail
  ret i32 %r
}
"""

_SAD_PLAIN = r"""
define internal i32 @sad(i8* noalias nocapture readonly %a, i8* noalias nocapture readonly %b, i64 %d) alwaysinline {
entry:
  %r = call i32 @sad_scalar(i8* %a, i8* %b, i64 %d)
  ret i32 %r
}
"""

# out[i * m + j] = pair(a + i d, b + j d) / d for every row i of a and the b rows j0..j1,
# tile by tile. {T}: element type, {PAIR}: the per-pair function, {WIDEN}: its sum to double.
_TILED = r"""
define void @{NAME}({T}* noalias nocapture readonly %a, {T}* noalias nocapture readonly %b, float* noalias nocapture %out,
                    i64 %n, i64 %m, i64 %d, i64 %j0, i64 %j1, i64 %tile) {{
entry:
  %dd = sitofp i64 %d to double
  br label %tiles
tiles:
  %t = phi i64 [%j0, %entry], [%tnext, %tile_done]
  %tleft = icmp ult i64 %t, %j1
  br i1 %tleft, label %tile_start, label %done
tile_start:
  %tend0 = add i64 %t, %tile
  %tshort = icmp ult i64 %tend0, %j1
  %tend = select i1 %tshort, i64 %tend0, i64 %j1
  br label %rows
rows:
  %i = phi i64 [0, %tile_start], [%inext, %row_done]
  %ileft = icmp ult i64 %i, %n
  br i1 %ileft, label %row_start, label %tile_done
row_start:
  %ioff = mul i64 %i, %d
  %pa = getelementptr inbounds {T}, {T}* %a, i64 %ioff
  %orow = mul i64 %i, %m
  br label %cols
cols:
  %j = phi i64 [%t, %row_start], [%jnext, %cols]
  %joff = mul i64 %j, %d
  %pb = getelementptr inbounds {T}, {T}* %b, i64 %joff
  %s = call {S} @{PAIR}({T}* %pa, {T}* %pb, i64 %d)
  %sf = {WIDEN} {S} %s to double
  %mean = fdiv double %sf, %dd
  %mf = fptrunc double %mean to float
  %oi = add i64 %orow, %j
  %po = getelementptr inbounds float, float* %out, i64 %oi
  store float %mf, float* %po, align 4
  %jnext = add nuw i64 %j, 1
  %jleft = icmp ult i64 %jnext, %tend
  br i1 %jleft, label %cols, label %row_done
row_done:
  %inext = add nuw i64 %i, 1
  br label %rows
tile_done:
  %tnext = add i64 %t, %tile
  br label %tiles
done:
  ret void
}}
"""

_SIGNATURE = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, *[ctypes.c_int64] * 6)


def host_has_avx2() -> bool:
    import llvmlite.binding as llvm

    return "+avx2" in llvm.get_host_cpu_features().flatten()


def module_source(kernel: str, avx2: bool) -> str:
    """The LLVM IR of one kernel: ``l1_u8`` (``avx2`` picks its pair function) or ``l1_f32``."""
    if kernel == "l1_u8":
        return _SAD_SCALAR + (_SAD_AVX2 if avx2 else _SAD_PLAIN) + _TILED.format(NAME="l1_u8", T="i8", S="i32", PAIR="sad", WIDEN="sitofp")
    return _ABS_FLOAT + _TILED.format(NAME="l1_f32", T="float", S="float", PAIR="l1f", WIDEN="fpext")


def cache_dir() -> Path:
    """Where compiled kernels are kept: ``$XDG_CACHE_HOME/placeloc/kernels`` (``~/.cache``)."""
    from placeloc.core.caches import cache_root

    return cache_root() / "kernels"


@functools.lru_cache(maxsize=4)
def kernel(name: str, avx2: bool | None = None) -> Any:
    """The compiled kernel ``name`` (``l1_u8`` or ``l1_f32``) as a ctypes function, once per
    process. ``avx2`` None: as the CPU allows. The machine code is cached on disk, keyed by
    the IR, the CPU and llvmlite's version (compiling both kernels takes about 0.1 s,
    loading them 4 ms, bench/bench_kernel_cache.py), only in a cache no one else can write (:func:`trusted_cache`);
    without one it is compiled every time."""
    if avx2 is None:
        avx2 = host_has_avx2()
    elif avx2 and not host_has_avx2():
        raise ValueError("this CPU lacks AVX2: use avx2=None or False")
    return compiled(name, module_source(name, bool(avx2)), _SIGNATURE)


# Kernels are loaded on a thread while localize starts (seqslam.matching): one at a time,
# so that a kernel asked for meanwhile is compiled or loaded once.
_COMPILE_LOCK = threading.Lock()


def compiled(name: str, source: str, signature: Any) -> Any:
    """The function ``name`` of the LLVM IR ``source``, compiled for this CPU (or loaded from
    the private on-disk cache, keyed by the IR, the CPU and llvmlite's version), as a ctypes
    function of type ``signature``; once per process. ctypes releases the GIL for the call."""
    return compiled_module(name, source, ((name, signature),))[name]


def compiled_module(module: str, source: str, functions: tuple[tuple[str, Any], ...]) -> dict[str, Any]:
    """Several functions of one IR module, ``(name, ctypes signature)`` each, as
    :func:`compiled` gives one: one engine and one cached object file for all (each engine
    costs about 7 ms to set up)."""
    with _COMPILE_LOCK:
        return _compiled(module, source, functions)


@functools.lru_cache(maxsize=16)
def _compiled(module: str, source: str, functions: tuple[tuple[str, Any], ...]) -> dict[str, Any]:
    import llvmlite
    import llvmlite.binding as llvm

    llvm.initialize_native_target()
    llvm.initialize_native_asmprinter()
    cpu, features = llvm.get_host_cpu_name(), llvm.get_host_cpu_features().flatten()
    key = hashlib.sha256("\0".join([source, cpu, features, llvmlite.__version__]).encode()).hexdigest()[:32]
    file_name = f"{module}-{key}.o"
    machine = llvm.Target.from_default_triple().create_target_machine(cpu=cpu, features=features, opt=3)
    engine = llvm.create_mcjit_compiler(llvm.parse_assembly(""), machine)
    folder = trusted_cache()
    secret = _secret(folder) if folder is not None else None
    cached = _load(folder, file_name, secret) if secret is not None else None
    if cached is not None:
        engine.add_object_file(llvm.ObjectFileRef.from_data(cached))
    else:
        mod = llvm.parse_assembly(source)
        mod.verify()
        passes = llvm.create_pass_builder(machine, llvm.create_pipeline_tuning_options(3))
        passes.getModulePassManager().run(mod, passes)
        obj = machine.emit_object(mod)
        engine.add_object_file(llvm.ObjectFileRef.from_data(obj))
        if secret is not None:
            _store(folder, file_name, obj, secret)
    engine.finalize_object()
    out = {}
    for name, signature in functions:
        fn = signature(engine.get_function_address(name))
        fn.engine = engine  # the engine owns the code: keep it alive with the function
        out[name] = fn
    return out


# A cached object is a few KB; anything larger is not one of ours.
_MAX_OBJECT_BYTES = 16 << 20
_SECRET_NAME = ".key"


def trusted_cache() -> Path | None:
    """The kernel cache folder (``$XDG_CACHE_HOME/placeloc/kernels``), or None when no one
    but this user may write it (:func:`placeloc.core.caches.private_cache_dir`)."""
    from placeloc.core.caches import private_cache_dir

    return private_cache_dir(cache_dir().name)


def _read_private(folder: Path, name: str, limit: int) -> bytes | None:
    """A private regular file of the cache (no link followed), at most ``limit`` bytes."""
    from placeloc.core.caches import is_private

    try:
        fd = os.open(folder / name, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return None
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or not is_private(st) or st.st_size > limit:
            return None
        return fh.read(limit + 1)


def _write_private(folder: Path, name: str, data: bytes) -> None:
    """Write a cache file 0600 (whatever the umask) under a temporary name, then rename."""
    tmp = folder / f".{name}.tmp-{os.getpid()}-{threading.get_ident()}"
    with contextlib.suppress(FileNotFoundError):
        tmp.unlink()
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
    try:
        os.fchmod(fd, 0o600)
        with os.fdopen(fd, "wb", closefd=False) as fh:
            fh.write(data)
    finally:
        os.close(fd)
    os.replace(tmp, folder / name)


def _secret(folder: Path) -> bytes | None:
    """This user's random key for the cache's digests, kept in the private folder (made on
    first use). An object file is trusted only with a digest made with it, so a file copied
    in from elsewhere, or one whose embedded checksum was recomputed, is never loaded."""
    secret = _read_private(folder, _SECRET_NAME, 64)
    if secret is not None and len(secret) == 32:
        return secret
    with contextlib.suppress(OSError):
        _write_private(folder, _SECRET_NAME, os.urandom(32))
        secret = _read_private(folder, _SECRET_NAME, 64)
    return secret if secret is not None and len(secret) == 32 else None


def _digest(secret: bytes, file_name: str, data: bytes) -> bytes:
    # the name is part of the digest: a valid object of one kernel cannot stand in for another
    return hmac.new(secret, file_name.encode() + b"\0" + data, hashlib.sha256).digest()


def _load(folder: Path, file_name: str, secret: bytes) -> bytes | None:
    """The machine code cached under ``file_name`` if it is a private regular file whose
    digest (keyed with this user's secret) holds; anything else is recompiled, never loaded
    (LLVM would also crash on a damaged object file)."""
    blob = _read_private(folder, file_name, _MAX_OBJECT_BYTES)
    if blob is None or len(blob) <= 32:
        return None
    digest, data = blob[:32], blob[32:]
    return data if hmac.compare_digest(_digest(secret, file_name, data), digest) else None


def _store(folder: Path, file_name: str, data: bytes, secret: bytes) -> None:
    """Cache the machine code with its keyed digest; a cache that cannot be written is skipped."""
    with contextlib.suppress(OSError):
        _write_private(folder, file_name, _digest(secret, file_name, data) + data)


def n_threads() -> int:
    """The cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def run_threaded(fn: Callable[[int, int], None], chunks: list[tuple[int, int]], threads: int | None = None) -> None:
    """``fn(lo, hi)`` for every chunk, on ``threads`` threads (None: one per core, never
    more than the chunks). For work that releases the GIL: ctypes kernels, NumPy."""
    threads = min(threads or n_threads(), len(chunks))
    if threads <= 1:
        for lo, hi in chunks:
            fn(lo, hi)
        return
    with ThreadPoolExecutor(max_workers=threads) as pool:
        list(pool.map(lambda c: fn(*c), chunks))


def _run_tiled(fn: Any, a: np.ndarray, b: np.ndarray, out: np.ndarray, threads: int | None) -> None:
    n, d = a.shape
    m = b.shape[0]
    if b.shape[1] != d or out.shape != (n, m) or out.dtype != np.float32:
        raise ValueError(f"shapes do not match: a {a.shape}, b {b.shape}, out {out.shape} {out.dtype}")
    for name, x in (("a", a), ("b", b), ("out", out)):
        if not x.flags.c_contiguous:
            raise ValueError(f"{name} must be C-contiguous")
    if n == 0 or m == 0:
        return
    # One contiguous run of whole tiles of b rows per thread.
    tiles = -(-m // _TILE)
    parts = max(1, min(threads or n_threads(), tiles))
    cuts = [min(m, (k * tiles // parts) * _TILE) for k in range(parts + 1)]
    args = (a.ctypes.data, b.ctypes.data, out.ctypes.data, n, m, d)
    run_threaded(lambda j0, j1: fn(*args, j0, j1, _TILE), list(zip(cuts[:-1], cuts[1:])), parts)


def l1_uint8(a: np.ndarray, b: np.ndarray, out: np.ndarray, *, threads: int | None = None,
             avx2: bool | None = None) -> None:
    """``out[i, j] = mean_k |a[i, k] - b[j, k]|``; ``a``, ``b`` C-contiguous uint8, ``out``
    float32 (the exact integer sum divided in double precision, then rounded to float32).
    ``threads`` None: every core; ``avx2`` None: as the CPU allows (False forces the plain loop)."""
    if a.dtype != np.uint8 or b.dtype != np.uint8:
        raise ValueError(f"l1_uint8 needs uint8 rows, got {a.dtype} and {b.dtype}")
    if a.shape[1] > MAX_UINT8_LENGTH:
        raise ValueError(f"rows of {a.shape[1]} bytes are too long for 32-bit sums (at most {MAX_UINT8_LENGTH})")
    _run_tiled(kernel("l1_u8", avx2), a, b, out, threads)


def l1_float(a: np.ndarray, b: np.ndarray, out: np.ndarray, *, threads: int | None = None) -> None:
    """``out[i, j] = mean_k |a[i, k] - b[j, k]|``; ``a``, ``b`` C-contiguous float32 (the sum
    is float32, in any order)."""
    if a.dtype != np.float32 or b.dtype != np.float32:
        raise ValueError(f"l1_float needs float32 rows, got {a.dtype} and {b.dtype}")
    _run_tiled(kernel("l1_f32"), a, b, out, threads)
