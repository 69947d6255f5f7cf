# Two commands a user needs: `make demo` and `make test`. Both set up .venv first.
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
TPU_STAMP := $(VENV)/.installed-tpu
WORKERS ?= 2
# XLA's CPU runtime allocates each step's large buffers afresh; glibc maps them with 4 KiB pages and
# the kernel faults them in again every step (about a fifth of a training step's CPU time here).
# Transparent huge pages for glibc's mapped chunks remove almost all of those faults: see the
# `minor_page_faults_per_step` of benchmarks/model.py. An explicit GLIBC_TUNABLES wins.
export GLIBC_TUNABLES ?= glibc.malloc.hugetlb=1
# make demo also keeps freed memory mapped (buffers up to 32 MiB, glibc's ceiling, from the heap; no trimming), so
# that a step reuses the last one's pages: its fine-tune 1.07x a step, where GR-ConvNet's step read 0.91x
# (benchmarks/malloc_settings.py, which reads both settings from here; results/performance/malloc_settings/),
# hence for make demo alone (the CNN figure is noisy: see there). An explicit GLIBC_TUNABLES wins here too.
KEEP_FREED := glibc.malloc.hugetlb=1:glibc.malloc.mmap_threshold=33554432:glibc.malloc.trim_threshold=17179869184:glibc.malloc.top_pad=268435456
DEMO_TUNABLES := $(if $(filter file,$(origin GLIBC_TUNABLES)),$(KEEP_FREED),$(GLIBC_TUNABLES))

.PHONY: setup demo test test-slow test-parity bench plan clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	@touch $(STAMP)

# The suite and the plan compile for TPU topologies with libtpu (the `tpu` extra: a 213 MB wheel),
# which the demo does not need: its set-up stays without it.
$(TPU_STAMP): $(STAMP)
	$(PY) -m pip install --quiet -e '.[test,tpu]'
	@touch $(TPU_STAMP)

demo: setup
	GLIBC_TUNABLES=$(DEMO_TUNABLES) $(PY) -m kosmos_jax.demo --config=configs/demo.py

test: $(TPU_STAMP)
	$(PY) -m pytest -n $(WORKERS) --dist loadgroup -q

test-slow: $(TPU_STAMP)
	$(PY) -m pytest -n $(WORKERS) --dist loadgroup -q -m slow

# The live comparison with transformers' PyTorch KOSMOS-2 (installs the CPU build of torch, ~1 GB).
test-parity: setup
	$(PY) -m pip install --quiet -e '.[test,parity]'
	$(PY) -m pytest -q -p no:xdist tests/test_model_parity.py

# benchmarks/cnn_cpu.py measures its peer in PyTorch, which .venv leaves out: its docstring says how to run it;
# timing.py is the others' helper and trace_summary.py reads a trace step_mfu.py --profile wrote
bench: setup
	for b in benchmarks/*.py; do case $$b in benchmarks/timing.py|benchmarks/cnn_cpu.py|benchmarks/trace_summary.py|benchmarks/malloc_settings.py) continue;; esac; \
		$(PY) $$b || exit 1; done

# The TPU memory plan: the `paper` step compiled for v5e, v4 and v6e slices by libtpu, no TPU attached
# (kosmos_jax/train/plan.py; minutes a topology on 2 cores). Another config or one topology:
# make plan PLAN_FLAGS="--config=configs/kosmos_e.py:tiny --topology=v5e:2x2 [--json]"
PLAN_FLAGS ?= --config=configs/kosmos_e.py:paper --plan
plan: $(TPU_STAMP)
	$(PY) -m kosmos_jax.train.compile $(PLAN_FLAGS)

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
