# Scaling with cores: the per-stage table of SeqSLAM's benchmark settings over workers
# 1, 2, 4, 8, 16 (bench/scaling.sh; no network needed, writes $(OUT)/scaling.md when OUT is set).
.PHONY: bench-scaling

bench-scaling:
	PYTHON=$(BIN)/python bench/scaling.sh
