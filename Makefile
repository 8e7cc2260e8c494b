# Every set-up step of the project. `make demo` and `make test` are the README's two commands.
PYTHON ?= python3
VENV := .venv
CARGO ?= cargo
DEMO_BAG := bags/synth-hard

.PHONY: all build demo test fuzz py-venv colcon-venv bench bags ort training-env ablations clean

all: build

build:
	$(CARGO) build --release

# Python readers (rosbags, mcap) and the reference evaluator's packages, for the test suite.
py-venv: $(VENV)/.stamp
$(VENV)/.stamp: scripts/requirements-eval.txt
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install --quiet --disable-pip-version-check -r scripts/requirements-eval.txt
	touch $@

# colcon, colcon-ros-cargo and cargo-ament-build (PyPI), for the colcon build test.
colcon-venv: .venv-colcon/.stamp
.venv-colcon/.stamp: scripts/requirements-colcon.txt
	$(PYTHON) -m venv .venv-colcon
	.venv-colcon/bin/pip install --quiet --disable-pip-version-check -r scripts/requirements-colcon.txt
	touch $@

# Main job on shipped data: replay a synthetic bag with each method, then score them.
demo: build ort
	rm -rf out/demo-angle-i2p out/demo-consistency out/demo-ransac
	./target/release/angle-i2p replay $(DEMO_BAG) --out out/demo-angle-i2p --method angle-i2p
	./target/release/angle-i2p replay $(DEMO_BAG) --out out/demo-consistency --method consistency
	./target/release/angle-i2p replay $(DEMO_BAG) --out out/demo-ransac --method ransac
	./target/release/angle-i2p eval $(DEMO_BAG) --est out/demo-angle-i2p --est out/demo-consistency --est out/demo-ransac --report out/demo-report

# The paper's ablations on the shared validation bags, each scored by eval (needs ../shared/data).
ablations: build ort
	./scripts/ablations.sh

# angle-i2p's methods beside PoseLib's LO-RANSAC, one table per bag (scripts/side_by_side.py):
# make side-by-side BAGS="../shared/data/redkitchen-hard-val …" [SIDE_BY_SIDE_ARGS="--method consistency …"]
BAGS ?= bags/synth-sift bags/synth-hard bags/synth-extreme
.PHONY: side-by-side
side-by-side: build ort py-venv
	$(VENV)/bin/python scripts/side_by_side.py $(BAGS) --out out/side-by-side \
		--binary $(or $(CARGO_TARGET_DIR),target)/release/angle-i2p $(SIDE_BY_SIDE_ARGS)

# All tests (unit, integration, Python-reader interop, evaluator agreement when ../shared is present).
test: py-venv ort colcon-venv
	./scripts/test_skips.sh clear
	ANGLE_I2P_PYTHON=$(abspath $(VENV))/bin/python $(CARGO) test --release --all-targets; \
	  status=$$?; ./scripts/test_skips.sh report; exit $$status

# Long fuzzing (minutes): the proptest targets of tests/fuzz.rs with many more cases than the
# suite's short mode. FUZZ_CASES raises or lowers it. A crash prints the shrunk input: keep it
# under tests/fixtures/fuzz/ (raw bytes; `.mcap` for a bag) so every later run replays it.
FUZZ_CASES ?= 20000
fuzz:
	ANGLE_I2P_FUZZ_CASES=$(FUZZ_CASES) $(CARGO) test --release --test fuzz -- --test-threads 2

bench:
	$(CARGO) bench

# Per-frame median and peak RSS against map size and bag length (synth --preset building bags);
# SIZES, LENGTHS, FRAMES, REPEAT as in scripts/scaling.sh. Writes out/scaling/scaling.md.
.PHONY: scaling
scaling: build
	BIN=$(or $(CARGO_TARGET_DIR),target)/release/angle-i2p ./scripts/scaling.sh

# ONNX Runtime's shared library (PyPI wheel onnxruntime==1.31.1) into .ort/, for the learned rejector.
ort:
	./scripts/fetch_onnxruntime.sh

# PyTorch 2.15.0 (CPU use) and its pinned libraries in training/.venv (~4.4 GB, once; not in CI).
training-env:
	bash training/setup.sh

# The model constants (network.* values each model was trained with) into the metadata of the
# models in models/, weights untouched (training/stamp_models.sh; train.py stamps new ones itself).
.PHONY: stamp-models
stamp-models:
	./training/stamp_models.sh

# Regenerate the synthetic bags shipped in bags/ (deterministic seeds).
bags: build
	./scripts/make_bags.sh

clean:
	rm -rf target out $(VENV) .ort training/.venv

# Behaviour check for refactors: replay the shipped and shared val bags with every method and
# compare digests of the outputs (timings left out) with tests/fixtures/output_digests.txt.
# `make digests` checks; `make digests DIGESTS=record` re-records after a deliberate change.
DIGESTS ?= check
.PHONY: digests
digests: build py-venv
	./scripts/output_digests.sh $(DIGESTS)
