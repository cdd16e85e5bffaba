"""The add-on's Blender layer: everything that imports ``bpy`` (operators, panels,
properties, preferences, cameras, the Gaussian object and its display, capture, the modal
driver, the steps "read Blender -> job -> build Blender data", the headless API). It imports
:mod:`..core`, never the other way round.
"""
