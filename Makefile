# Two entry points, both from nothing: `make demo` and `make test` (the whole suite); `make check` is the fast
# tier a developer runs often: ruff, then every test that starts no ROS and needs no root (minutes, not tens).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

# what ruff checks: the whole repository (narrow it for a moment with `make check RUFF_PATHS=tests`)
RUFF_PATHS ?= .

.PHONY: demo lint check test bench clean

# The version is checked before .venv is made (pip's own error names no fix); a .venv whose set-up failed
# (no stamp) is made again, not reused.
$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2>/dev/null || { \
	  echo "cq_ros needs Python 3.11 (pyproject's requires-python); $(PYTHON) is $$($(PYTHON) --version 2>/dev/null || echo not found): run make PYTHON=python3.11" >&2; exit 1; }
	rm -rf $(VENV)
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	@echo "installing cq-ros and its dependencies (ROS 2 included) into $(VENV): about a minute" >&2
	$(BIN)/python -m pip install --progress-bar on -e '.[test,cluster,view,colcon]'
	touch $(STAMP)

# the demo's ROS domain: `make demo DOMAIN=N`, else the environment's ROS_DOMAIN_ID, else one drawn in 100..200
demo: $(STAMP)
	$(BIN)/cq-ros launch --map tunnel_to_goal --algo cq --episodes 300 --seed 1 --out results/demo --force \
	  $(if $(DOMAIN),--domain-id $(DOMAIN))

lint: $(STAMP)
	$(BIN)/ruff check $(RUFF_PATHS)

check: lint
	$(BIN)/python -m pytest -m "not ros and not root"

test: lint
	$(BIN)/python -m pytest

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_engine.py

clean:
	rm -rf $(VENV) results
