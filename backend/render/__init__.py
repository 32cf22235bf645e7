"""Condition-layer renderer (docs/design.md §4.3): points z-buffer and Gaussian splatting, in torch (CPU or CUDA)."""
