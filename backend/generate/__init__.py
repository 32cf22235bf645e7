"""The generate command: the SCPainter model or the inpainting baseline, and the MP4 writer."""
