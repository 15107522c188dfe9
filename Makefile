# One command each: `make test`, `make demo`, `make bench`. Each installs what is
# missing first (tools/setup.sh is idempotent and takes about a second when warm).
SHELL := /bin/bash
RUN := source ./env.sh &&
PYTEST_ARGS ?=

.PHONY: setup test demo bench clean

setup:
	@./tools/setup.sh

test: setup
	@$(RUN) python -m pytest $(PYTEST_ARGS)

demo: setup
	@$(RUN) temoto demo

bench: setup
	@$(RUN) python bench/run_all.py

clean:
	rm -rf .venv build runs .pytest_cache
	find . -path ./.git -prune -o \( -path '*/msg/*.py' -o -path '*/srv/*.py' \) -print -delete >/dev/null
