"""Radiance fields on top of kernels.volume: rendering images from Cameras, and fitting to datasets."""
