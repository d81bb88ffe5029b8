# gesture_pose developer targets. Every target that runs Python first creates .venv from
# requirements.txt (stamp file .venv/.stamp), so they all work on a fresh clone.

PY ?= $(or $(shell command -v python3.11 2>/dev/null),python3)
VENV := .venv
VENV_PY := $(VENV)/bin/python
STAMP := $(VENV)/.stamp
# Comma-separated subset of linux-x64,windows-x64,macos-arm64,macos-x64 (default: all).
PLATFORMS ?=
LINT_PATHS := gesture_pose tests bench tools sample_scenes

.PHONY: all venv test demo sample-scenes bench lint extension clean

all: test

$(STAMP): requirements.txt
	$(PY) -m venv $(VENV)
	$(VENV_PY) -m pip install -r requirements.txt
	touch $@

venv: $(STAMP)

test: $(STAMP)
	$(VENV_PY) -m pytest -q tests

SCENES := $(addprefix sample_scenes/,humanoid.blend tentacle.blend quadruped.blend abstraction.blend stick.blend)

# Rebuild the sample scenes on request; `make demo` only builds those that are missing.
sample-scenes: $(STAMP)
	$(VENV_PY) sample_scenes/make_scenes.py

$(SCENES): | $(STAMP)
	$(VENV_PY) sample_scenes/make_scenes.py

demo: $(STAMP) $(SCENES)
	$(VENV_PY) tools/demo.py

bench: $(STAMP)
	$(VENV_PY) bench/run.py

lint: $(STAMP)
	$(VENV_PY) -m ruff check $(LINT_PATHS)

extension: $(STAMP)
	$(VENV_PY) tools/build_extension.py $(if $(PLATFORMS),--platforms $(PLATFORMS))

# Keeps .venv (use `rm -rf .venv` to rebuild it) and the sample .blend files.
clean:
	rm -rf build dist .pytest_cache .ruff_cache
	find . -path ./$(VENV) -prune -o -name __pycache__ -type d -prune -exec rm -rf {} +
