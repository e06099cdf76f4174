#!/bin/bash
# The per-stage scaling table (workers 1, 2, 4, 8, 16) of SeqSLAM's benchmark settings at
# 3576 x 3576 (bench/scaling.py), for a many-core machine without network: it needs only
# the working tree and its .venv. Frames come from /work/shared/data/nordland-dev when
# present, else from the synthetic route generator. Writes $OUT/scaling.md when OUT is set.
#   bench/scaling.sh                       # workers 1,2,4,8,16
#   WORKERS=1,2 N=600 bench/scaling.sh     # a quick check
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-.venv/bin/python}
[ -x "$PY" ] || PY=python3
# 7.5 minutes at most: what is measured by then is printed; a half-finished table is not written.
exec timeout 450 "$PY" bench/scaling.py --n "${N:-3576}" --workers "${WORKERS:-1,2,4,8,16}" --repeat "${REPEAT:-2}" "$@"
