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

# The Blender-side tests (the add-on inside bpy: tests/scene, tests/runs, tests/cli, tests/street, the demo) on bpy 4.2 LTS and 4.5 LTS,
# each in its own environment built by tools/lts_envs.sh (LTS_VENV_DIR moves them; ~4.5 GB each). The street is
# built once by the project's own bpy 5.0.1 (.venv), so every version reads the same ground truth. Both versions
# run even when the first fails; the target fails if either did (docs/design.md §6).
.PHONY: test-blender-lts
BLENDER_SIDE_TESTS = tests/scene tests/runs tests/cli tests/street tests/test_demo.py
test-blender-lts: setup
	.venv/bin/python -c "from scpainter_blender.street.dataset import ensure_street; ensure_street()"
	@bash tools/lts_envs.sh
	@status=0; for v in 42 45; do \
	  echo "== bpy $$v: $(BLENDER_SIDE_TESTS)"; \
	  "$${LTS_VENV_DIR:-.}/.venv-bpy$$v/bin/python" -m pytest -p no:cacheprovider $(BLENDER_SIDE_TESTS) || status=1; \
	done; exit $$status
