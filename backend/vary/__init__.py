"""``vary`` (variants of a base job, ``core.variation``) and ``contact-sheet`` (their first frames, for people)."""
