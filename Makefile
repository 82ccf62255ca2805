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

# External validators (ign sdf, Khronos glTF validator); skipped with a note if absent.
tools:
	@bash .ci/install-tools

scene: $(STAMP)
	$(BIN)/twin build --sources $(SOURCES) --out $(OUT) $(if $(JOBS),--jobs $(JOBS))
	$(BIN)/twin validate --sources $(SOURCES) --out $(OUT)

validate: $(STAMP)
	$(BIN)/twin validate --sources $(SOURCES) --out $(OUT)

test: $(STAMP)
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/twin bench --sources $(SOURCES) --out $(OUT)

clean:
	rm -rf $(OUT)
