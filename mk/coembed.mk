# Co-embedding mapper: the paper's simulation and tears-of-steel, and the solver benchmark.
.PHONY: experiment-coembed bench-coembed

experiment-coembed: $(STAMP)
	$(PL) experiment coembed

bench-coembed: $(STAMP)
	$(BIN)/python bench/bench_coembed.py
