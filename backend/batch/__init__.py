"""Many jobs: the sequential / torchrun-sharded batch and the Ray pool."""
