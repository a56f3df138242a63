# canopen_master: one entry point. `make help` lists the targets.
# Every simulation uses GHDL's LLVM back end (Debian's default is mcode).
export GHDL_BACKEND := llvm
export PYTHONDONTWRITEBYTECODE := 1

VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.requirements.sha256
RTL    := $(shell sed -e 's/\#.*//' -e '/^[[:space:]]*$$/d' -e 's|^|rtl/|' rtl/files.f)
TB_VHD := $(wildcard tb/vhdl/*.vhd)
PYDIRS := tb sim_models scripts

.PHONY: help setup test demo lint synth-check synth bench fuzz waves docs drift-report clean

help:
	@echo "make setup        install Debian packages (ghdl-llvm, yosys) and the pinned .venv"
	@echo "make demo         set up if needed, run the most complete system simulation"
	@echo "make test         set up if needed, lint + synthesizability check + all tests"
	@echo "make synth        GHDL + yosys synth_intel cycloneive: LUT/FF/M9K/levels (SYNTH_ARGS=-j1)"
	@echo "make bench        benchmarks -> build/bench/results.json"
	@echo "make fuzz         one fuzz-bench seed: FUZZ_SEED=<n> make fuzz (unset: random, printed)"
	@echo "make waves TEST='<pytest id>'   re-run one test with a .ghw waveform"
	@echo "make docs         render the WaveDrom timing diagrams in docs/wavedrom"
	@echo "make drift-report Omni-ID clock-drift plots and dropout tables -> build/drift"
	@echo "make clean        remove build outputs"

# set-up runs when the venv is missing or the pinned requirements changed
$(STAMP): requirements.txt requirements.lock scripts/setup.sh
	./scripts/setup.sh

setup:
	./scripts/setup.sh

demo: $(STAMP)
	$(PY) scripts/demo.py

# VSG exits 0 on warnings; any reported line (error or warning) fails the lint here.
# sensitivity.py: every combinational process lists exactly the signals it reads (VHDL-93)
lint: $(STAMP)
	@out=$$($(VENV)/bin/vsg -c scripts/vsg.yaml -of syntastic -f $(RTL) $(TB_VHD)); \
	  if [ -n "$$out" ]; then echo "$$out"; echo "VSG: violations above"; exit 1; fi; \
	  echo "VSG: $(words $(RTL) $(TB_VHD)) files clean"
	$(VENV)/bin/ruff check $(PYDIRS)
	$(PY) scripts/sensitivity.py

synth-check: $(STAMP)
	$(PY) scripts/synth.py --check

test: lint synth-check
	$(PY) -m pytest -n auto --maxschedchunk=1 -m "not bench" -q

synth: $(STAMP)
	$(PY) scripts/synth.py $(SYNTH_ARGS)

bench: synth
	$(PY) scripts/bench.py

# one seed of the system fuzz bench (docs/fuzz_bench.md); FUZZ_EPOCHS, FUZZ_EPOCH_MS,
# FUZZ_CLASSES, FUZZ_TRACE, FUZZ_REPORT are passed through from the environment
fuzz: $(STAMP)
	FUZZ_SEED=$(or $(FUZZ_SEED),random) $(PY) -m pytest -p no:xdist -q -rA -s \
	  tb/test_fuzz_system.py::test_fuzz_seed

waves: $(STAMP)
	@test -n "$(TEST)" || { echo "usage: make waves TEST='tb/test_x.py::test_x[params]'"; exit 2; }
	rm -f build/sim/last_waves.txt
	WAVES=1 $(PY) -m pytest -q -p no:xdist "$(TEST)"
	@echo "waveform(s):"; cat build/sim/last_waves.txt

docs: $(STAMP)
	$(PY) scripts/render_wavedrom.py

drift-report: $(STAMP)
	$(PY) scripts/drift_report.py

clean:
	rm -rf build .pytest_cache .ruff_cache
	find . -name __pycache__ -prune -exec rm -rf {} +
