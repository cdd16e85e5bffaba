"""Blender-side scene generation: seeded builders (``scenes.builders``) and Cycles rendering
(``scenes.render``). Imports bpy; the data it writes is read by ``prosplat.data`` without it."""
