"""SCPainter backend: the torch side, run as ``python -m backend <command>`` in a subprocess (docs/design.md §2,
§4.4).

Importing this package imports nothing heavy: each command imports what it needs when it runs, so ``doctor`` on a
machine without a GPU never initialises CUDA.
"""
