# Fault tests on their own, with a table: case, outcome, exit code, seconds, last stderr line.
.PHONY: faults
faults: $(STAMP)
	$(BIN)/python tests/faults_table.py
