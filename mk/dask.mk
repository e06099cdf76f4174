# Dask executor: scaling benchmark. Needs the dask extra for its LocalCluster row.
.PHONY: bench-scale

bench-scale: $(STAMP)
	$(BIN)/python -m pip install -q -e '.[dask]'
	$(BIN)/python bench/bench_scale.py
