"""Shared fixtures. The helper modules beside this file (``synthetic_scenes``, ``posed_data``,
``addon_support``, ...) are importable from every test folder: pyproject's ``pythonpath``
puts ``tests/`` on ``sys.path``."""
