# SeqSLAM: the comparison experiment, the speed benchmark and the presets on real data.
.PHONY: experiment-seqslam bench-seqslam bench-seqslam-large seqslam-nordland seqslam-corridor seqslam-route

experiment-seqslam: $(STAMP)
	$(PL) experiment seqslam

bench-seqslam: $(STAMP)
	$(BIN)/python bench/bench_seqslam.py

bench-seqslam-large: $(STAMP)
	$(BIN)/python bench/bench_seqslam.py --large
