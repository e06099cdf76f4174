#!/bin/bash
# Every scaling table in one go, for a many-core machine without network (it needs only the
# working tree and the packages; `make bench-many-cores`):
#   1. SeqSLAM's stages pinned to 1, 2, 4, ..., nproc cores, benchmark settings, and its
#      localize kernels over the same cores (seqslam-cores);
#   2. the same with the Nordland preset, the flexible search (preset-cores);
#   3. SeqSLAM's stages over executor.workers 1, 2, 4, ..., nproc on every core (seqslam-workers);
#   4. SeqSLAM's per-image work over threads, by image size (image-threads);
#   4b. where the preset's localize numerics spend their wall time on 1, 2, ..., nproc cores,
#      part by part (seqslam-timeline); the same on nproc, nproc / 2 and 1 cores with the
#      flexible search's tiles 4096, 1024 and 512 references (preset-tiles);
#   5. UMap's whole-panorama search over numba threads (umap), and UMap's localize on a
#      generated home as a user runs it, pinned to 1, 2, ..., nproc cores (umap-home;
#      UMAP_PANORAMAS=32 for the real home's count, UMAP_WORK=dir to keep or reuse the home);
#   6. co-embedding's sparse solve over cores (coembed);
#   7. PIRF's default index over faiss threads (pirf; skipped without faiss).
# Each table has its own time limit, so one that runs long costs only itself. Tables go to
# $OUT (default runs/many-cores/) as markdown as each finishes; everything printed goes to
# $OUT/all.log. Frames come from $PLACELOC_SHARED_DATA/nordland-dev when set (tiled with
# noise, as on the development machines), else from the synthetic route generator.
#   bench/many_cores.sh
#   N=600 TABLES="seqslam-cores umap" bench/many_cores.sh   # a quick check of two tables
set -uo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-.venv/bin/python}
[ -x "$PY" ] || PY=python3
OUT=${OUT:-runs/many-cores}
mkdir -p "$OUT"
export PYTHONPATH=$PWD/pipeline${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
N=${N:-3576}
TABLES=${TABLES:-seqslam-cores preset-cores seqslam-workers image-threads seqslam-timeline preset-tiles umap umap-home coembed pirf}
exec > >(tee -a "$OUT/all.log") 2>&1

"$PY" - <<'EOF'
import os, platform, sys
import cv2, numba, numpy, scipy
print(platform.platform(), "| python", sys.version.split()[0], "| numpy", numpy.__version__, "| numba", numba.__version__,
      "| opencv", cv2.__version__, "| scipy", scipy.__version__)
print("cores", os.cpu_count(), "usable", len(os.sched_getaffinity(0)), "| load", os.getloadavg())
EOF

# Byte-compile the tree before timing anything: where a process cannot keep its compiled
# modules (PYTHONDONTWRITEBYTECODE, a tree copied fresh or read-only), every placeloc process
# compiles from source the modules it imports. A 16-core H100 host that lends itself for
# these tables sets PYTHONDONTWRITEBYTECODE=1; a localize there spent 0.23-0.42 s in
# builtins.compile (docs/architecture.md, "Process start-up").
echo "PYTHONDONTWRITEBYTECODE=${PYTHONDONTWRITEBYTECODE:-unset}"
"$PY" -m compileall -q pipeline bench cli.py > /dev/null || echo "compileall failed: timings include compiling the modules"

table() {  # name, seconds allowed, command...
    local name=$1 limit=$2
    shift 2
    case " $TABLES " in *" $name "*) ;; *) return ;; esac
    echo "== $name (limit ${limit} s) $(date +%T)"
    timeout "$limit" "$@"
    echo "== $name: exit $? $(date +%T)"
}

table seqslam-cores 130 "$PY" bench/scaling.py --n "$N" --repeat 2 --cores --out "$OUT/seqslam-cores.md"
table preset-cores 150 "$PY" bench/scaling.py --n "$N" --repeat 1 --cores --preset --out "$OUT/preset-cores.md"
table seqslam-workers 100 "$PY" bench/scaling.py --n "$N" --repeat 2 --no-kernels --out "$OUT/seqslam-workers.md"
table image-threads 60 "$PY" bench/bench_image_threads.py --n "$N" --repeat 2
table seqslam-timeline 90 "$PY" bench/bench_seqslam_timeline.py --frames "$N"
HALVES=$("$PY" -c "import os; n = len(os.sched_getaffinity(0)); print(','.join(map(str, sorted({n, max(1, n // 2), 1}, reverse=True))))")
table preset-tiles 200 "$PY" bench/bench_seqslam_timeline.py --frames "$N" --cores "$HALVES" --tiles 4096,1024,512
table umap 150 "$PY" bench/bench_umap.py --panorama-only
table umap-home 180 "$PY" bench/bench_umap_home.py --repeat 2 --panoramas "${UMAP_PANORAMAS:-20}" ${UMAP_WORK:+--work "$UMAP_WORK"}
table coembed 40 "$PY" bench/bench_coembed.py
if "$PY" -c "import faiss" 2>/dev/null; then
    PIRF_CACHE=$(mktemp -d -t placeloc-pirf-XXXXXX)
    table pirf 60 "$PY" bench/bench_pirf.py --size "${PIRF_SIZE:-100000}" --backends bruteforce,faiss-hnsw-tuned --cache "$PIRF_CACHE"
    rm -rf "$PIRF_CACHE"
else
    echo "== pirf: skipped (no faiss)"
fi
echo "== done $(date +%T)"
