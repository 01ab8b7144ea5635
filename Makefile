# carlaocc — every target bootstraps .venv itself on a fresh machine.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
# Unset variables pass nothing, so the root's remembered plan (<root>/plan.yaml) supplies them;
# a variable given changes that knob of the plan (and the run remembers the new plan).
RES    ?=
ROOT   ?= data
FRAMES ?=
SEQUENCES ?=
CONFIG ?=
WORKERS ?=
PLAN   ?=
STAGE  ?= voxelize
TEST_JOBS ?= 2
Q      ?= SELECT table_name FROM information_schema.tables ORDER BY 1
SCHEDULER ?=
SCHED_ARG := $(if $(SCHEDULER),--scheduler $(SCHEDULER),)
PLAN_ARGS := $(if $(RES),--res $(RES),) $(if $(FRAMES),--limit-frames $(FRAMES),) \
             $(if $(SEQUENCES),--sequences '$(SEQUENCES)',) $(if $(CONFIG),--config $(CONFIG),) \
             $(if $(filter default,$(PLAN)),--default-plan,)
RUN_ARGS  := $(PLAN_ARGS) $(if $(WORKERS),--workers $(WORKERS),) $(SCHED_ARG)

.DEFAULT_GOAL := help
.PHONY: help venv syslibs-test venv-test venv-docs dataset stage query status info test test-all bench docs clean-venv syslibs

help: ## list the targets
	@echo "carlaocc make targets"
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-10s %s\n", $$1, $$2}'
	@echo "variables (unset: the root's remembered plan, <ROOT>/plan.yaml, decides; set: changes it):"
	@echo "  ROOT=<dir>          dataset root (default: data)"
	@echo "  RES=<m>[,<m>...]    voxel sizes, e.g. RES=0.2 or RES=0.2,0.1"
	@echo "  FRAMES=<n>          only the first n frames of every sequence (n >= 2), e.g. FRAMES=2"
	@echo "  SEQUENCES=<globs>   only these sequences, e.g. SEQUENCES='town00_*'"
	@echo "  CONFIG=<file>       a dataset config (YAML/JSON; see carlaocc config)"
	@echo "  WORKERS=<n>         LocalCluster workers (default: one per core; not remembered)"
	@echo "  PLAN=default        forget the remembered plan: back to the default plan"
	@echo "  STAGE=<name>        make stage: the stage to run alone"
	@echo "  Q=\"<sql>\"           make query: the SQL"
	@echo "  SCHEDULER=<addr|synchronous>  a Dask scheduler instead of a LocalCluster"
	@echo "  TEST_JOBS=<n>       make test: processes running the suite (default 2; 0: one, in make's)"
	@echo "example: make dataset FRAMES=2        (a first build in about 2 minutes)"
	@exit 0

syslibs: ## install the system packages .venv needs (Debian/Ubuntu: apt-get as root, else sudo -n)
	@sh tools/setup_system.sh "$(PYTHON)"

$(BIN)/.installed: pyproject.toml | syslibs
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e .
	@touch $@

# the test extra (pytest, hypothesis, torch, moto...) only for `make test`: `make dataset` never
# installs a test-only package
$(BIN)/.installed-test: pyproject.toml $(BIN)/.installed
	$(BIN)/pip install -q -e '.[test]'
	# nuscenes-devkit for the NDS cross-check test only: it pins numpy<2, so it lives apart
	# (--no-deps, its own directory on the test's PYTHONPATH), never beside carlaocc's packages
	$(BIN)/pip install -q --no-deps --target $(VENV)/nuscenes-devkit nuscenes-devkit==1.2.0 pyquaternion==0.9.9
	@touch $@

# the docs extra (mkdocs-material, mkdocstrings) only for `make docs`
$(BIN)/.installed-docs: pyproject.toml $(BIN)/.installed
	$(BIN)/pip install -q -e '.[docs]'
	@touch $@

venv: syslibs $(BIN)/.installed ## create .venv with what building needs (no test packages)

# the system packages of the tests only (a headless Chromium for the browser tests), checked on every
# `make test` (nothing is done when present); `make dataset` never installs a browser
syslibs-test:
	@sh tools/setup_system.sh --test "$(PYTHON)"

venv-test: venv syslibs-test $(BIN)/.installed-test ## add the test extra to .venv (make test does it)

venv-docs: venv $(BIN)/.installed-docs ## add the docs extra to .venv (make docs does it)

dataset: venv ## build the dataset on the remembered plan: make dataset FRAMES=2 RES=0.2 ROOT=data
	$(BIN)/carlaocc run --root $(ROOT) $(RUN_ARGS)

stage: venv ## re-run one stage alone on the remembered plan: make stage STAGE=voxelize
	$(BIN)/carlaocc run --stages $(STAGE) --root $(ROOT) $(RUN_ARGS)

status: venv ## what is stale in ROOT and why (the remembered plan unless variables say otherwise)
	$(BIN)/carlaocc status --root $(ROOT) $(PLAN_ARGS)

info: venv ## what ROOT holds: sequences, frames, voxel sizes, splits, label table, size
	$(BIN)/carlaocc info --root $(ROOT)

query: venv ## read-only SQL over the catalog: make query Q="SELECT * FROM assets LIMIT 5"
	$(BIN)/carlaocc catalog query "$(Q)" --root $(ROOT)

# the suite runs in TEST_JOBS processes (pytest-xdist), a test file per process at a time (its module
# fixtures are built once); TEST_JOBS=0 runs it in this process
test: venv-test ## the test suite (slow tests excluded; CI runs this): make test TEST_JOBS=2
	$(BIN)/python -m pytest -q -m "not slow" --durations=15 $(if $(filter-out 0,$(TEST_JOBS)),-n $(TEST_JOBS) --dist loadfile,)

test-all: venv-test ## every test, the slow 0.05 m end-to-end included
	$(BIN)/python -m pytest -q $(if $(filter-out 0,$(TEST_JOBS)),-n $(TEST_JOBS) --dist loadfile,)

bench: venv-test ## speed benchmarks against the libraries a user would otherwise use
	$(BIN)/python -m benchmarks

docs: venv-docs ## build the manual into site/ (warnings are errors; open site/index.html)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

clean-venv:
	rm -rf $(VENV)
