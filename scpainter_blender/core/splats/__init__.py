"""Gaussian splat files and values: one record per file format (``formats``), their readers, TRELLIS, SH."""
