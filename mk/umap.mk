# UMap: synthetic corridor experiment and the 36k-view database benchmark.
.PHONY: experiment-umap bench-umap

experiment-umap: $(STAMP)
	$(PL) experiment umap

bench-umap: $(STAMP)
	$(BIN)/python bench/bench_umap.py
