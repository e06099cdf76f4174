# PIRF-nav2 (issue 6): `make experiment-pirf` reproduces the paper's tables 2-4 and
# figs. 4-7 on a generated omnidirectional video; `make bench-pirf` measures m_t speed
# and agreement of every index backend against brute force at a 500,000-entry dictionary.
.PHONY: experiment-pirf experiment-pirf-quick bench-pirf

experiment-pirf: $(STAMP)
	$(PL) experiment pirf

experiment-pirf-quick: $(STAMP)
	$(PL) experiment pirf --quick

bench-pirf: $(STAMP)
	$(BIN)/python bench/bench_pirf.py
