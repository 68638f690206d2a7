# Every target installs what it needs into .venv from nothing.
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip
STAMP  := $(VENV)/.installed
export PIP_CONSTRAINT := $(CURDIR)/constraints.txt

.PHONY: venv run test test-all bench lint clean proto test-packages

venv: $(STAMP)

$(STAMP): pyproject.toml clients/python/pyproject.toml constraints.txt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PIP) install -q --upgrade pip
	$(PIP) install -q torch==2.13.0
	$(PIP) install -q -e '.[dev]'
	$(PIP) install -q -e clients/python
	touch $(STAMP)

## The main job on the embedded default: nbake serve on a free port, a render job of cornell_box over
## HTTP with its progress, the artifact's files downloaded to out/run/, the server stopped.
run: venv
	$(PY) -m services.cli.run_job --scene cornell_box --preset default --config '{"spp": 64}' --out out/run

## Debian packages the tests use: Chromium for the dashboard's browser test (Playwright drives it; it never
## downloads a browser) and assimp's BSD sample models for the glTF importer's real-file test.
TEST_PACKAGES := chromium assimp-testmodels
test-packages:
	dpkg -s $(TEST_PACKAGES) >/dev/null 2>&1 || (apt-get update -q && \
		DEBIAN_FRONTEND=noninteractive apt-get install -y -q $(TEST_PACKAGES))

## The default test suite (what CI runs), in TEST_WORKERS processes, a test file each at a time: the suite
## spends about half its time waiting on servers, Ray and subprocesses, so two workers on this 2-core machine
## took it from 17:09 (one process, kernels compiling) to 11:26 (compiled), 1437 tests both ways; the
## same CPU time (10:20 and 9:03 user). TEST_WORKERS=0 runs it in one process.
TEST_WORKERS ?= 2
PYTEST := $(VENV)/bin/pytest -q -n $(TEST_WORKERS) --dist loadfile
test: venv test-packages
	$(PYTEST) --durations=30

## Including slow accuracy checks.
test-all: venv test-packages
	$(PYTEST) -m ''

bench: venv
	$(PY) -m tests.bench

lint: venv
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/lint-imports
	$(VENV)/bin/hadolint docker/Dockerfile

## Regenerate the gRPC stubs from proto/ into the client package (the server imports them from there).
PROTO_OUT ?= clients/python
proto: venv
	$(PY) -m grpc_tools.protoc -I proto --python_out=$(PROTO_OUT) \
		--grpc_python_out=$(PROTO_OUT) proto/neuralbake/v1/*.proto

clean:
	rm -rf $(VENV) out .pytest_cache
