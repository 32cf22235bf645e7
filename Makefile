# The two commands of the README: `make demo` (the main job on the built-in street) and `make test`.
.PHONY: setup demo test bench train-street clean-cache

setup:
	@bash tools/setup.sh

demo: setup
	.venv/bin/python tools/demo.py $(ARGS)

test: setup
	.venv/bin/python -m pytest

train-street: setup
	.venv/bin/python tools/train_street.py $(ARGS)

bench: setup
	.venv/bin/python bench/bench_import.py

clean-cache:
	rm -rf .cache
