#!/bin/bash
# Every scaling table in one go, for a many-core machine without network (it needs only the
# working tree and the packages; `make bench-many-cores`):
#   1. SeqSLAM's stages over executor.workers 1, 2, 4, ..., nproc, benchmark settings;
#   2. the same with the Nordland preset (the flexible search);
#   3. the preset's extract + localize pinned to 1, 2, ..., nproc cores;
#   4. UMap's whole-panorama search over numba threads;
#   5. co-embedding's sparse solve over cores;
#   6. PIRF's default index over faiss threads (skipped without faiss).
# Each table has its own time limit, so one that runs long costs only itself. Tables go to
# $OUT (default runs/many-cores/) as markdown as each finishes; everything printed goes to
# $OUT/all.log. Frames come from $PLACELOC_SHARED_DATA/nordland-dev when set (tiled with
# noise, as on the development machines), else from the synthetic route generator.
#   bench/many_cores.sh
#   N=600 TABLES="seqslam-bench umap" bench/many_cores.sh   # a quick check of two tables
set -uo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-.venv/bin/python}
[ -x "$PY" ] || PY=python3
OUT=${OUT:-runs/many-cores}
mkdir -p "$OUT"
export PYTHONPATH=$PWD/pipeline${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
N=${N:-3576}
TABLES=${TABLES:-seqslam-bench seqslam-preset preset-cores umap coembed pirf}
exec > >(tee -a "$OUT/all.log") 2>&1

"$PY" - <<'EOF'
import os, platform, sys
import cv2, numba, numpy, scipy
print(platform.platform(), "| python", sys.version.split()[0], "| numpy", numpy.__version__, "| numba", numba.__version__,
      "| opencv", cv2.__version__, "| scipy", scipy.__version__)
print("cores", os.cpu_count(), "usable", len(os.sched_getaffinity(0)), "| load", os.getloadavg())
EOF

table() {  # name, seconds allowed, command...
    local name=$1 limit=$2
    shift 2
    case " $TABLES " in *" $name "*) ;; *) return ;; esac
    echo "== $name (limit ${limit} s) $(date +%T)"
    timeout "$limit" "$@"
    echo "== $name: exit $? $(date +%T)"
}

table seqslam-bench 160 "$PY" bench/scaling.py --n "$N" --repeat 2 --out "$OUT/seqslam-bench.md"
table seqslam-preset 130 "$PY" bench/scaling.py --n "$N" --repeat 1 --preset --stages extract,localize,evaluate \
    --out "$OUT/seqslam-preset.md"
table preset-cores 100 "$PY" bench/scaling.py --n "$N" --repeat 1 --preset-cores
table umap 60 "$PY" bench/bench_umap.py --panorama-only
table coembed 40 "$PY" bench/bench_coembed.py
if "$PY" -c "import faiss" 2>/dev/null; then
    table pirf 60 "$PY" bench/bench_pirf.py --size "${PIRF_SIZE:-100000}" --backends bruteforce,faiss-hnsw-tuned --cache /tmp/placeloc-pirf-cache
else
    echo "== pirf: skipped (no faiss)"
fi
rm -rf /tmp/placeloc-pirf-cache
echo "== done $(date +%T)"
