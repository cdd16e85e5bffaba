"""The pipeline's stages: the ``ProSplat`` model (:mod:`prosplat.pipeline.model.model`), enhancing a
rendered view, the depth sweep, refinement, distillation and the user's own posed views.
"""
