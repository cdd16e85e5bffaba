"""Geometry with no model in it: Gaussians per pixel and for holes, the Gaussian budget, which
input views to use, image matching and the input rig's near/far.
"""
