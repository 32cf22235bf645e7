"""Mesh cars: mesh files into Z-up parts, their colours and boxes, surface Gaussians, silhouettes."""
