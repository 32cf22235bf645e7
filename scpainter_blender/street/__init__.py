"""The ground-truth street: a procedural street rendered by Cycles, written in VGGT's layout (see dataset.py)."""
