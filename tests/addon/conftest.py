"""Fixtures of the add-on's bpy tests (each test file skips itself where bpy is missing)."""

from __future__ import annotations

import pytest


@pytest.fixture
def blank():
    """An empty factory scene with the add-on registered; returns the scene."""
    pytest.importorskip("bpy")
    from addon_support import reset_scene

    return reset_scene()
