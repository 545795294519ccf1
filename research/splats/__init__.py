"""3D Gaussian splatting on top of kernels/splat: the model, its PLY files, Adam,
the L1 + D-SSIM loss, densification and the training loop (Kerbl et al. 2023)."""
