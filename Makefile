# Every target installs the Debian packages it uses (.ci/system-packages, as root) and the npm
# packages of the tests (.ci/node-packages: the independent OPC UA client), creates
# .venv on first use and installs the project (editable, with its test and gige extras). The
# stamp file makes re-runs quiet and fast; it is rebuilt when pyproject.toml changes.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test bench lint clean

$(STAMP): pyproject.toml .ci/system-packages .ci/node-packages tests/plant/node_client/package-lock.json
	@bash .ci/system-packages
	@bash .ci/node-packages
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	@$(BIN)/python -m pip install -q --disable-pip-version-check --upgrade pip
	@$(BIN)/python -m pip install -q --disable-pip-version-check -e '.[test]'
	@# PyGObject (GigE Vision) is built from source: without the Debian build packages it
	@# fails, and only the GigE tests skip (they say why).
	@$(BIN)/python -m pip install -q --disable-pip-version-check -e '.[gige]' \
		|| echo "make: PyGObject could not be built; the GigE Vision tests will skip and say why"
	@touch $(STAMP)

# heliocal demo exits 3 when one of its nights ended partial (a geometry not measured: the
# table it prints says which); the demonstration itself ran to its end, so make says so and
# succeeds. Any other failure fails make.
demo: $(STAMP)
	@$(BIN)/heliocal demo --uncalibrated 12; rc=$$?; \
	if [ $$rc -eq 3 ]; then echo "make demo: a night ended partial (heliocal demo exit 3; the table above says which)"; \
	elif [ $$rc -ne 0 ]; then exit $$rc; fi

# Three workers on the 2-core machine: many tests wait on a plant clock, a subprocess or a
# server, and a third worker fills those waits (448 s against 570 s for -n 2, 2026-11-30).
test: $(STAMP)
	$(BIN)/python -m pytest -q -n 3 --dist loadgroup

bench: $(STAMP)
	@for b in benchmarks/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

lint: $(STAMP)
	$(BIN)/ruff check .

clean:
	rm -rf $(VENV) build *.egg-info
