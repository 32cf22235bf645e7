"""Training: the trainer and its helpers (data, logging)."""
