# placeloc: every experiment and benchmark is a target. `make demo` and `make test` work
# on a fresh machine with only Python 3.10+: they create .venv and install placeloc.
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin
PL      = $(BIN)/placeloc
STAMP   = $(VENV)/.installed

.PHONY: help venv demo test lint clean bench-seqslam-peer

help:
	@echo "make demo               set up .venv, run SeqSLAM on data-samples, print and explain its figures"
	@echo "make test               set up .venv, run the test suite"
	@echo "make lint               ruff"
	@echo "make experiment-seqslam reproduce the SeqSLAM comparison (corridor, nordland-dev, synthetic)"
	@echo "make bench-seqslam      SeqSLAM speed and memory benchmark (3576 x 3576)"
	@echo "make bench-seqslam-large  ... plus a 36,000 x 36,000 run (several minutes, ~10 GB disk)"
	@echo "make bench-seqslam-peer PEER_BIN=path [LOAD=2] [PAIRS=5]  whole run beside the C++ peer (TimQuelch/seqslam), 5 alternating pairs"
	@echo "make seqslam-presets    SeqSLAM presets: chosen on one part of nordland-dev/corridor, reported on the other"
	@echo "make experiment-umap    UMap and UMap+CA on the synthetic corridor building, panoramas in 5 generated homes"
	@echo "make experiment-umap-phone  UMap on photos taken by hand: tilted, cropped photo spheres (test homes, ~4 min)"
	@echo "make experiment-umap-plan   UMap with a plan whose ceiling height is not known (test homes, ~15 min)"
	@echo "make experiment-umap-scale  UMap with a plan drawn 5-10 % too small or too large (test homes, ~15 min)"
	@echo "make experiment-umap-halves UMap's score halves weighted otherwise: chosen on 13 homes, checked on 5 (~25 min)"
	@echo "make experiment-umap-lines  UMap's shortest photo line kept: chosen on 13 homes, checked on 5 (~20 min)"
	@echo "make experiment-umap-contrast UMap's photo contrast equalised before LSD: chosen on 13 homes, checked on 5 (~25 min)"
	@echo "make bench-umap         UMap database rendering and scoring speed"
	@echo "make experiment-coembed co-embedding vs Isomap vs PCAMD (simulation, tears-of-steel)"
	@echo "make bench-coembed      co-embedding sparse solve at 10,000 x 2,000"
	@echo "make experiment-pirf    PIRF-nav2 tables 2-4 and figs 4-7 on generated omni video"
	@echo "make experiment-pirf-large  ... at 8,000 frames, dictionary past 300,000 entries (~30 min)"
	@echo "make experiment-pirf-dictionary  PIRF plain vs improved dictionary as slow motion and sideways revisits grow (~75 min)"
	@echo "make bench-pirf         PIRF m_t: ANN backends vs brute force at 500,000 entries"
	@echo "make bench-scale        extraction throughput: inline, process pool, Dask LocalCluster"
	@echo "make bench-scaling      per-stage SeqSLAM table over workers 1, 2, 4, 8, 16 (3576 x 3576; OUT=dir writes scaling.md)"
	@echo "make bench-scaling-preset  the Nordland preset (flexible search) pinned to 1, 2, 4, ..., nproc cores"
	@echo "make bench-many-cores   every scaling table in one go, about 5 minutes on 16 cores (OUT=dir keeps them)"
	@echo "make bench-seqslam-timeline  where the preset's localize spends its wall time on 1, 2, ..., nproc cores"
	@echo "make bench-umap-home    UMap localize on a generated home pinned to 1, 2, ..., nproc cores"
	@echo "make faults             the fault tests alone, one table row per case (outcome, rc, seconds, last line)"

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[dev,dask,experiments]'
	touch $(STAMP)

venv: $(STAMP)

# Byte-code for placeloc's own modules, written each time (only changed files are compiled
# again). An editable install writes none, and where PYTHONDONTWRITEBYTECODE is set (CI and
# container images often set it) Python writes none either: then every stage process
# compiles the modules it imports from source again (0.08 s of an evaluate's 0.38 s at
# 3576 x 3576; the tests start hundreds of stage processes).
BYTECODE = $(BIN)/python -m compileall -q pipeline cli.py > /dev/null

demo: $(STAMP)
	@$(BYTECODE)
	$(PL) run configs/demo.yaml --run-dir runs/demo
	@echo
	@echo "Results in runs/demo: report.html (open it in a browser), metrics.json, per_query.csv, matches.csv, *.png"
	@echo "(to type 'placeloc' instead of $(PL): source $(BIN)/activate)"
	@$(BIN)/python -m placeloc.seqslam.demo runs/demo

test: $(STAMP)
	@$(BYTECODE)
	$(BIN)/python -m pytest -q -p no:cacheprovider

lint: $(STAMP)
	$(BIN)/ruff check .

clean:
	rm -rf runs .pytest_cache

# The C++ peer is not part of this repository: PEER_BIN is the whole-run driver built against
# it (bench/bench_seqslam_peer.py --help says how). Without it this target says so and stops.
PEER_BIN ?=
LOAD ?= 0
PAIRS ?= 5
bench-seqslam-peer: $(STAMP)
	@if [ -z "$(PEER_BIN)" ] || [ ! -x "$(PEER_BIN)" ]; then \
		echo "bench-seqslam-peer: no peer driver (PEER_BIN='$(PEER_BIN)'); build it as 'bench/bench_seqslam_peer.py --help' says, then: make bench-seqslam-peer PEER_BIN=/path/to/peer-run"; \
	else \
		$(BIN)/python bench/bench_seqslam_peer.py --peer-bin "$(PEER_BIN)" --load $(LOAD) --pairs $(PAIRS); \
	fi

-include mk/*.mk
