# The two commands of the README: `make demo` (the main job on the built-in street) and `make test`.
.PHONY: setup demo test test-backend-only bench train-street clean-cache

setup:
	@bash tools/setup.sh

demo: setup
	.venv/bin/python tools/demo.py $(ARGS)

test: setup
	.venv/bin/python -m pytest

# The backend and core tests in a backend-only environment (requirements-backend.txt: numpy 2, current OpenCV, no
# bpy), as on a GPU machine; Blender's tests skip, saying so. The street's tests need the street cached (`make test`).
test-backend-only:
	@bash tools/setup_backend.sh
	.venv-backend/bin/python -m pytest tests/core tests/backend

train-street: setup
	.venv/bin/python tools/train_street.py $(ARGS)

bench: setup
	.venv/bin/python bench/bench_import.py

clean-cache:
	rm -rf .cache
