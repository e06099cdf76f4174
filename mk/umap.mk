# UMap: synthetic corridor experiment, the generated homes (defaults chosen on development
# homes, reported on others) and the benchmarks (36k-view database, real-scale floor,
# whole-panorama search against the search before it, per panorama).
.PHONY: experiment-umap experiment-umap-homes experiment-umap-phone experiment-umap-plan experiment-umap-scale experiment-umap-halves experiment-umap-lines experiment-umap-contrast bench-umap

experiment-umap: $(STAMP)
	$(PL) experiment umap

bench-umap: $(STAMP)
	$(BIN)/python bench/bench_umap.py

experiment-umap-homes: $(STAMP)
	$(PL) experiment umap-homes

experiment-umap-phone: $(STAMP)
	$(PL) experiment umap-phone

experiment-umap-plan: $(STAMP)
	$(PL) experiment umap-plan

experiment-umap-scale: $(STAMP)
	$(PL) experiment umap-scale

experiment-umap-halves: $(STAMP)
	$(PL) experiment umap-halves

experiment-umap-lines: $(STAMP)
	$(PL) experiment umap-lines

experiment-umap-contrast: $(STAMP)
	$(PL) experiment umap-contrast
