# carlaocc — every target bootstraps .venv itself on a fresh machine.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
RES    ?= 0.2
ROOT   ?= data
STAGE  ?= voxelize
Q      ?= SELECT table_name FROM information_schema.tables ORDER BY 1
SCHEDULER ?=
SCHED_ARG := $(if $(SCHEDULER),--scheduler $(SCHEDULER),)

.DEFAULT_GOAL := help
.PHONY: help venv dataset stage query status test test-all bench clean-venv syslibs

help: ## list the targets
	@echo "carlaocc make targets (variables: RES=<m>[,<m>...] ROOT=<dir> STAGE=<name> Q=\"<sql>\" SCHEDULER=<addr|synchronous>)"
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-10s %s\n", $$1, $$2}'

syslibs: ## install the system packages .venv needs (Debian/Ubuntu: apt-get as root, else sudo -n)
	@sh tools/setup_system.sh "$(PYTHON)"

$(BIN)/.installed: pyproject.toml | syslibs
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e '.[test]'
	# nuscenes-devkit for the NDS cross-check test only: it pins numpy<2, so it lives apart
	# (--no-deps, its own directory on the test's PYTHONPATH), never beside carlaocc's packages
	$(BIN)/pip install -q --no-deps --target $(VENV)/nuscenes-devkit nuscenes-devkit==1.2.0 pyquaternion==0.9.9
	@touch $@

venv: syslibs $(BIN)/.installed ## create .venv and install carlaocc with its test dependencies

dataset: venv ## build the whole dataset on the embedded default: make dataset RES=0.2 ROOT=data
	$(BIN)/carlaocc run --res $(RES) --root $(ROOT) $(SCHED_ARG)

stage: venv ## re-run one stage alone: make stage STAGE=voxelize RES=0.1
	$(BIN)/carlaocc run --stages $(STAGE) --res $(RES) --root $(ROOT) $(SCHED_ARG)

status: venv ## what is stale in ROOT and why
	$(BIN)/carlaocc status --res $(RES) --root $(ROOT)

query: venv ## read-only SQL over the catalog: make query Q="SELECT * FROM assets LIMIT 5"
	$(BIN)/carlaocc catalog query "$(Q)" --root $(ROOT)

test: venv ## the test suite (slow tests excluded; CI runs this)
	$(BIN)/python -m pytest -q -m "not slow" --durations=15

test-all: venv ## every test, the slow 0.05 m end-to-end included
	$(BIN)/python -m pytest -q

bench: venv ## speed benchmarks against the libraries a user would otherwise use
	$(BIN)/python -m benchmarks

clean-venv:
	rm -rf $(VENV)
