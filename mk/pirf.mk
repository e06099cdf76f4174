# PIRF-nav2 (Sasaki and Hamagami): `make experiment-pirf` reproduces the paper's tables 2-4 and
# figs. 4-7 on a generated omnidirectional video; `make bench-pirf` measures m_t speed
# and agreement of every index backend against brute force at a 500,000-entry dictionary.
.PHONY: experiment-pirf experiment-pirf-quick experiment-pirf-large experiment-pirf-dictionary bench-pirf

experiment-pirf: $(STAMP)
	$(PL) experiment pirf

# 8,000 frames: the dictionary passes 300,000 entries (about 30 min on 2 cores)
experiment-pirf-large: $(STAMP)
	$(PL) experiment pirf-large

# plain vs improved dictionary size as slow motion, sideways revisits and stitching-seam ghosting grow
# (33 videos, about 2 hours on 2 shared cores; one setting alone: python -m placeloc.experiments.pirf_dictionary --only seam)
experiment-pirf-dictionary: $(STAMP)
	$(PL) experiment pirf-dictionary

experiment-pirf-quick: $(STAMP)
	$(PL) experiment pirf --quick

bench-pirf: $(STAMP)
	$(BIN)/python bench/bench_pirf.py
