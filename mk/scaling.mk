# Scaling with cores: the per-stage table of SeqSLAM's benchmark settings over workers
# 1, 2, 4, 8, 16 (bench/scaling.sh; no network needed, writes $(OUT)/scaling.md when OUT is set).
.PHONY: bench-scaling

bench-scaling:
	PYTHON=$(BIN)/python bench/scaling.sh

# The Nordland preset (the flexible search): extract + localize as processes pinned to
# 1, 2, 4, ..., nproc cores (the goal: both cores of a 2-core machine at least 1.6x one),
# and the preset's localize numerics alone over the same core counts.
.PHONY: bench-scaling-preset
bench-scaling-preset: $(STAMP)
	$(BIN)/python bench/scaling.py --preset-cores
	$(BIN)/python bench/bench_seqslam_full.py --scaling

# Every scaling table in one go (SeqSLAM's stages with both settings, the preset pinned to
# cores, UMap, co-embedding, PIRF), each under its own time limit; OUT=dir keeps them.
.PHONY: bench-many-cores
bench-many-cores: $(STAMP)
	PYTHON=$(BIN)/python bench/many_cores.sh

# Where the preset's localize numerics spend their wall time on 1, 2, 4, ..., nproc cores,
# part by part (the difference blocks, the flexible search's families, ...).
.PHONY: bench-seqslam-timeline
bench-seqslam-timeline: $(STAMP)
	$(BIN)/python bench/bench_seqslam_timeline.py

# UMap's localize on a generated home (experiment umap-homes' seed 21, 1,494 positions) as
# a user runs it, pinned to 1, 2, 4, ..., nproc cores.
.PHONY: bench-umap-home
bench-umap-home: $(STAMP)
	$(BIN)/python bench/bench_umap_home.py
