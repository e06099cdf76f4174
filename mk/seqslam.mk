# SeqSLAM: the comparison experiment, the speed benchmark and the presets on real data.
.PHONY: experiment-seqslam bench-seqslam bench-seqslam-large seqslam-nordland seqslam-corridor seqslam-route seqslam-presets \
	seqslam-speed seqslam-speed-tune seqslam-motion seqslam-motion-tune seqslam-motion-quick bench-seqslam-full \
	bench-seqslam-preset-ratio

experiment-seqslam: $(STAMP)
	$(PL) experiment seqslam

bench-seqslam: $(STAMP)
	$(BIN)/python bench/bench_seqslam.py

bench-seqslam-large: $(STAMP)
	$(BIN)/python bench/bench_seqslam.py --large

# Presets on real data (needs ../shared/data): the whole data set, one command each ...
seqslam-nordland: $(STAMP)
	$(PL) run configs/nordland.yaml --run-dir runs/nordland

seqslam-corridor: $(STAMP)
	$(PL) run configs/corridor.yaml --run-dir runs/corridor

seqslam-route: $(STAMP)
	$(PL) run configs/route.yaml --run-dir runs/route

# ... and the figures of docs/seqslam.md: chosen on one part, reported on the other.
seqslam-presets: $(STAMP)
	$(BIN)/python -m placeloc.experiments.seqslam --out runs/seqslam-presets

# Query speed that changes (steady, varying 0.5-2.0x, stopping): settings chosen on
# nordland-dev frames 1-600 (seeds 0-4), reported on 601-1200 (seeds 100-104) through
# `placeloc run`; the table of docs/seqslam.md ("When the speed changes").
seqslam-speed-tune: $(STAMP)
	$(BIN)/python -m placeloc.experiments.seqslam_speed tune --out runs/seqslam-speed

seqslam-speed: $(STAMP)
	$(BIN)/python -m placeloc.experiments.seqslam_speed report --out runs/seqslam-speed

# A query that stops, crawls, bursts past 2x and reverses (docs/seqslam.md, "A query that
# stops, crawls, bursts and reverses"): the path model chosen on nordland-dev frames 1-600
# (seeds 0-2), reported on 601-1200 (seeds 200-204; --seeds 100-104 for the earlier rounds'
# seeds); --quick for CI (450 frames, 2 seeds).
seqslam-motion-tune: $(STAMP)
	$(BIN)/python -m placeloc.experiments.seqslam_motion tune --out runs/seqslam-motion

seqslam-motion: $(STAMP)
	$(BIN)/python -m placeloc.experiments.seqslam_motion report --out runs/seqslam-motion

seqslam-motion-quick: $(STAMP)
	$(BIN)/python -m placeloc.experiments.seqslam_motion report --quick --out runs/seqslam-motion-quick

# The Nordland preset's localize at the whole route's size (35,768 x 35,768; run it on a
# quiet machine: about 10-30 minutes), and its cost against straight trajectories at the
# same window and speeds (3576 x 3576, alternating, one run).
bench-seqslam-full: $(STAMP)
	$(BIN)/python bench/bench_seqslam_full.py --frames 35768 --only preset

bench-seqslam-preset-ratio: $(STAMP)
	$(BIN)/python bench/bench_seqslam_full.py --frames 3576
