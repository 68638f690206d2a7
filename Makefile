# Every target installs what it needs into .venv from nothing.
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip
STAMP  := $(VENV)/.installed
export PIP_CONSTRAINT := $(CURDIR)/constraints.txt

.PHONY: venv lock run test test-all bench lint clean proto docs test-packages

venv: $(STAMP)

$(STAMP): requirements/dev.txt pyproject.toml clients/python/pyproject.toml constraints.txt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PIP) install -q pip==$(PIP_VERSION)
	$(PIP) install -q torch==2.13.0 -r requirements/dev.txt
	$(PIP) install -q --no-deps --no-build-isolation -e . -e clients/python  # built by the locked setuptools
	$(PIP) check
	touch $(STAMP)

## Every install path takes its versions from a lock in requirements/, written by pip-compile from the
## pyproject.toml files: dev.txt (server, dev extra and client: `make venv` and CI), server.txt (server and client: the
## images) and client.txt (a user's CI image), the last two constrained to dev.txt's versions. torch is left out of
## all three: it is pinned above and in constraints.txt, and its wheel (CPU or CUDA) differs by machine.
## Run `make lock` after editing a pyproject.toml (tests/unit/test_lock.py fails until you do); existing
## pins are kept unless a requirement moves them: `make lock LOCK_FLAGS=--upgrade` takes the newest.
PIP_VERSION := 26.3
LOCK_FLAGS ?=
COMPILE = $(PY) -m piptools compile -q --strip-extras --unsafe-package torch --no-emit-find-links \
	--no-emit-index-url $(LOCK_FLAGS)
lock: venv
	$(COMPILE) --extra dev -o requirements/dev.txt pyproject.toml clients/python/pyproject.toml
	$(COMPILE) -c requirements/dev.txt -o requirements/server.txt pyproject.toml clients/python/pyproject.toml
	$(COMPILE) -c requirements/dev.txt -o requirements/client.txt clients/python/pyproject.toml

## The main job on the embedded default: nbake serve with its inference service on free ports, a quick lod
## model of the Menger sponge trained and served, its frame beside the path-traced reference and the
## report's speed-against-error line in out/run/ (scripts/first-run.sh; about a minute here), all stopped.
run: venv
	bash scripts/first-run.sh

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

## Rewrite docs/kinds/<kind>.md, every registered kind's parameter table, from its config's schema and
## presets (scripts/kind_docs.py); tests/unit/test_kind_docs.py fails while a page is stale.
docs: venv
	$(PY) -m scripts.kind_docs

## Regenerate the gRPC stubs from proto/ into the client package (the server imports them from there).
PROTO_OUT ?= clients/python
proto: venv
	$(PY) -m grpc_tools.protoc -I proto --python_out=$(PROTO_OUT) \
		--grpc_python_out=$(PROTO_OUT) proto/neuralbake/v1/*.proto

clean:
	rm -rf $(VENV) out .pytest_cache
