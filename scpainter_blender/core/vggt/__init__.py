"""VGGT's predictions: conventions and values, the npz file, white-border crop, pose convention."""
