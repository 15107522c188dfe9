# One command each: `make test`, `make demo`, `make bench`. Each installs what is
# missing first (tools/setup.sh is idempotent and takes about a second when warm).
SHELL := /bin/bash
RUN := source ./env.sh &&
PYTEST_ARGS ?=

.PHONY: setup test demo bench clean

setup:
	@./tools/setup.sh

# Two phases: the suite on 2 workers, then the tests marked `alone`, which load the whole machine on purpose
# and would starve the other worker's sensors into real stalls. Exit code 5 is "nothing selected".
test: setup
	@$(RUN) python -m pytest -m 'not alone' $(PYTEST_ARGS)
	@$(RUN) python -m pytest -n 0 -m alone $(PYTEST_ARGS) || [ $$? -eq 5 ]

demo: setup
	@$(RUN) temoto demo

bench: setup
	@$(RUN) python bench/run_all.py

clean:
	rm -rf .venv build runs .pytest_cache
	find . -path ./.git -prune -o \( -path '*/msg/*.py' -o -path '*/srv/*.py' \) -print -delete >/dev/null
