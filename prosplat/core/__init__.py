"""The core types every part speaks: cameras, Gaussians, rotations, PLY and image files,
checkpoints and output paths.
"""
