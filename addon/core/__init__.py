"""The add-on's bpy-free half: nothing here imports ``bpy`` or ``mathutils``, at module level
or in a function, nor anything from :mod:`..blender`; it imports only its own siblings, the
standard library, numpy and (inside jobs) ``prosplat``. So it runs, and is tested, in plain
Python (``tests/addon/test_addon_layers.py``), and the Blender layer imports it one way.

- :mod:`.splat_math`: the splat display's numpy maths and Blender 5.3's native splat layout
- :mod:`.jobs`, :mod:`.worker_process`: a worker task in a thread or an external process
- :mod:`.requirements`, :mod:`.pins`, :mod:`.install`: what prosplat needs, the tested set,
  and the pip install of it
- :mod:`.depthsplat_file`: what a DepthSplat file name says (model, licence, training size)
- :mod:`.photos`: *Import Photos*' source (a folder or a video), pose folder and names
"""
