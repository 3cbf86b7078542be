# Every target goes through .venv/bin/python so `make demo` and `make test` each work
# on a fresh clone. The stamp reinstalls only when pyproject.toml changes.
PY := .venv/bin/python
STAMP := .venv/.installed

.PHONY: install demo test bench bench-faults bench-diagnose bench-diagnose-ci lint release train clean

install: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(PY) || python3 -m venv .venv
	$(PY) -m pip install --quiet --upgrade pip
	# torch first: this exact release is the local CPU wheel; anything else pulls CUDA.
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

demo: install
	$(PY) -m lads.demo --out demo_output

test: install
	$(PY) -m pytest -q

bench: install
	$(PY) -m benchmarks.run_all

# The fault-injection campaign of `lads build` on the real SemanticKITTI frames (~15 min):
# tried / caught / survived / lost per fault class -> benchmarks/results/faults.json.
bench-faults: install
	$(PY) -m benchmarks.faults

# The concealed-effect benchmark of `lads diagnose` (docs/diagnose.md §6): every case x 20 seeds x
# both bases (offline, hours), and a CI-sized subset (~5 min).
bench-diagnose: install
	$(PY) -m benchmarks.diagnose_bench --full

bench-diagnose-ci: install
	$(PY) -m benchmarks.diagnose_bench --subset ci

lint: install
	$(PY) -m ruff check lads tests benchmarks
	$(PY) -m ruff format --check lads tests benchmarks
	$(PY) -m mypy lads

# The LADS table from the dataset roots in LADS_*_ROOT (see lads/release.py); without
# them, a demo release from synthetic sources. Verified, with cards and manifests.
release: install
	$(PY) -m lads.release

# The shipped intensity weights and their model cards, from the real frames in TRAIN_DATA
# (CPU, 2 cores: ~15 min, measured 13 min on 2026-11-27): `lads train NAME --data-root DIR`, the command users run, with the output
# pointed at the package's weights folder.
TRAIN_CONFIGS = synth-to-kitti synth-to-nuscenes weather
TRAIN_DATA ?= ../shared/data
train: install
	for c in $(TRAIN_CONFIGS); do \
	  .venv/bin/lads train $$c --data-root $(TRAIN_DATA) --output lads/intensity/weights/$$c.pt || exit 1; \
	done
	$(PY) -m lads.intensity.model_card --weights-dir lads/intensity/weights --docs docs/intensity \
	  --data-root $(TRAIN_DATA) $(TRAIN_CONFIGS)

clean:
	rm -rf .venv demo_output dist release
