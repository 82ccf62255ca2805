# Two commands set everything up on a fresh machine: `make scene` and `make test`.
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
SOURCES ?= sources
OUT    ?= build
JOBS   ?=

.PHONY: scene test validate bench clean venv tools

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[blender,test,authoring]'
	touch $(STAMP)

venv: $(STAMP)

# External validators (ign sdf, Khronos glTF validator, Chromium for the report test):
# installed on first use by `make scene` and `make test` (apt needs root or sudo).
TOOLS  := tools/node_modules/.installed

$(TOOLS): tools/package-lock.json .ci/install-tools tools/gzprobe/gzprobe.cc tools/gzprobe/common.cc \
          tools/gzprobe/physics.cc tools/gzprobe/probe.hh tools/gzprobe/Makefile tools/gzbridge/gzbridge.cc \
           tools/gzbridge/Makefile
	bash .ci/install-tools
	touch $(TOOLS)

tools: $(TOOLS)

# pipeline/'s bytecode, compiled ahead: an editable install leaves the package without
# it, and where PYTHONDONTWRITEBYTECODE is set (it is on this machine) every process
# compiles each module it imports again: the CLI, every build worker, every Blender
# process (a test run starts hundreds). compileall writes only what is missing
# or stale; Python still checks each file's timestamp, so an edit is compiled anew.
BYTECODE = $(BIN)/python -m compileall -q -j 0 pipeline > /dev/null

scene: $(STAMP) $(TOOLS)
	$(BYTECODE)
	$(BIN)/twin build --sources $(SOURCES) --out $(OUT) $(if $(JOBS),--jobs $(JOBS))
	$(BIN)/twin validate --sources $(SOURCES) --out $(OUT)

validate: $(STAMP)
	$(BIN)/twin validate --sources $(SOURCES) --out $(OUT)

# The suite on every core (pytest-xdist) and one worker more: some tests wait more than
# they compute (a dask cluster or a browser starting, a killed run's clock, a live
# twin's ticks), and with a worker per core the cores stand idle whenever such tests
# run on all of them at once. Tests that share a costly module fixture run on one
# worker together (their xdist_group marks), the others one by one; the twenty slowest
# are listed at the end.
TEST_WORKERS ?= $(shell echo $$(( $$(nproc 2>/dev/null || echo 1) + 1 )))
# The suite makes and deletes tens of thousands of files (builds, renders, copies of
# them); on a disk filesystem the kernel's bookkeeping of them is a good part of the
# run's CPU. Where /dev/shm (a filesystem in memory) has room for a run's files and
# margin (6 GB), the tests' temporary folders go there (a folder per user); elsewhere,
# or with TEST_TMPDIR= , they stay in TMPDIR. A passed run leaves none of its tests'
# files there (tmp_path_retention_policy).
TEST_TMPDIR ?= $(shell avail=$$(df -Pk /dev/shm 2>/dev/null | awk 'NR == 2 {print $$4}'); \
	[ -w /dev/shm ] && [ "$${avail:-0}" -ge 6291456 ] && echo /dev/shm/substation-twin-tests-$$(id -u))

# PYTHONDONTWRITEBYTECODE emptied: pytest keeps the test modules as it rewrote their
# asserts (tests/__pycache__) only where Python may write bytecode, and each worker
# rewrites every module again otherwise, at every run.
test: $(STAMP) $(TOOLS)
	$(BYTECODE)
	tmp='$(TEST_TMPDIR)'; if [ -n "$$tmp" ]; then mkdir -p "$$tmp" && export TMPDIR="$$tmp"; fi; \
	PYTHONDONTWRITEBYTECODE= $(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadgroup --durations=20

bench: $(STAMP) $(TOOLS)
	$(BYTECODE)
	$(BIN)/twin bench --sources $(SOURCES) --out $(OUT)

clean:
	rm -rf $(OUT)
