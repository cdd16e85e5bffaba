"""A DepthSplat checkpoint in the add-on's *Generator Weights*: Reconstruct runs it through
``ProSplat.from_pretrained(generator=...)`` in the worker and the Gaussians render; a wrong
file is one clear line in the status bar, never a traceback; the preferences say the file's
licence and the Input Size that matches it. The checkpoint is the random-weights small model
in the released format (tests/pipeline/test_depthsplat_pipeline.py), at 64 px."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

pytestmark = pytest.mark.blender
bpy = pytest.importorskip("bpy")

from addon_support import data_counts, reset_scene, run_op  # noqa: E402
from synthetic_scenes import write_synthetic_scene  # noqa: E402

from addon.blender import pointcloud, preferences, runtime, steps  # noqa: E402
from addon.core import depthsplat_file  # noqa: E402
from prosplat.core.image_io import read_image  # noqa: E402
from prosplat.generator.depthsplat import random_encoder, save_released_format  # noqa: E402
from prosplat.generator.depthsplat.config import SMALL  # noqa: E402

NAME = "depthsplat-gs-small-re10k-256x256-view2-cfeab6b1.pth"
SIZE = 64


@pytest.fixture(scope="module")
def released_file(tmp_path_factory) -> Path:
    return save_released_format(random_encoder(SMALL, 7), tmp_path_factory.mktemp("ds") / NAME)


@pytest.fixture
def prefs(monkeypatch):
    """The add-on's settings as a test sets them (the add-on is registered, not enabled, so
    it reads :class:`runtime.Defaults`): raw renders, the scene's own size, Blender's Python."""
    p = runtime.Defaults(enhance=False, max_input_size=SIZE)
    monkeypatch.setattr(runtime, "prefs", lambda context=None: p)
    return p


@pytest.fixture
def inputs(tmp_path: Path):
    """Views 000 and 002 of the analytic demo scene imported as inputs (001 is a target)."""
    reset_scene()
    write_synthetic_scene(tmp_path / "s", size=SIZE, n_views=3)
    res, err = run_op(bpy.ops.prosplat.import_posed_images, filepath=str(tmp_path / "s"))
    assert res == {"FINISHED"}, err
    return bpy.context.scene.prosplat.inputs


def test_reconstruct_with_a_depthsplat_file_gives_gaussians_that_render(
    inputs, prefs, released_file, tmp_path: Path, monkeypatch
) -> None:
    prefs.weights_path = str(released_file)
    scene = bpy.context.scene
    reports: list[str] = []  # the operator's INFO line, kept to assert on
    describe = steps.describe_reconstruct
    monkeypatch.setattr(
        steps, "describe_reconstruct", lambda r: reports.append(describe(r)) or reports[-1]
    )
    res, err = run_op(bpy.ops.prosplat.reconstruct)
    assert res == {"FINISHED"}, err
    assert "with DepthSplat small" in reports[0] and "non-commercial" not in reports[0]
    g = scene.prosplat.gaussians
    assert g is not None and 0 < pointcloud.point_count(g) <= 2 * SIZE * SIZE
    assert list(g[steps.MADE_SIZE_PROP]) == [SIZE, SIZE]

    scene.prosplat.output_dir = str(tmp_path / "renders")
    res, err = run_op(bpy.ops.prosplat.render_view)  # the imported target camera, view 001
    assert res == {"FINISHED"}, err
    image = read_image(tmp_path / "renders" / "001.png")
    assert image.shape == (3, SIZE, SIZE) and torch.isfinite(image).all()
    assert float(image.std()) > 0.01  # Gaussians drew something, not a flat background


@pytest.mark.parametrize(
    "content, says",
    [
        ({"state_dict": {"model.weight": torch.zeros(2)}}, "is not a DepthSplat checkpoint"),
        (b"not a pickle at all", "could not be read as a PyTorch checkpoint"),
    ],
)
def test_a_wrong_file_is_one_clear_line(inputs, prefs, tmp_path: Path, content, says) -> None:
    path = tmp_path / "depthsplat-gs-small-wrong.pth"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        torch.save(content, path)
    prefs.weights_path = str(path)
    before = data_counts()
    res, err = run_op(bpy.ops.prosplat.reconstruct)
    assert res == {"CANCELLED"} and says in err and path.name in err, err
    assert "Traceback" not in err and "\n" not in err.strip()
    assert data_counts() == before  # nothing half-made


def test_a_missing_file_is_named(inputs, prefs, tmp_path: Path) -> None:
    prefs.weights_path = str(tmp_path / NAME)
    res, err = run_op(bpy.ops.prosplat.reconstruct)
    assert res == {"CANCELLED"} and "not found" in err and NAME in err, err


class _Layout:
    """Records what a draw function puts in the panel."""

    def __init__(self, log: list) -> None:
        self.log = log

    def box(self):
        return self

    def label(self, text: str = "", icon: str = "NONE") -> None:
        self.log.append((text, icon))


def test_preferences_show_licence_and_input_size_for_a_depthsplat_file() -> None:
    log: list = []
    small = type("P", (), {"weights_path": "//models/" + NAME, "max_input_size": 256})()
    preferences.draw_depthsplat_note(_Layout(log), small)
    text = " | ".join(t for t, _ in log)
    assert "DepthSplat small" in text and "Apache-2.0" in text and "commercial use allowed" in text
    assert "Trained at 256x256: Input Size 256 matches it" in text and "(now" not in text

    log.clear()
    base = "depthsplat-gs-base-re10kdl3dv-448x768-randview2-6-f8ddd845.pth"
    preferences.draw_depthsplat_note(
        _Layout(log), type("P", (), {"weights_path": base, "max_input_size": 256})()
    )
    assert ("MIT + CC-BY-NC-4.0 (Depth Anything V2 ViT-B): non-commercial use only", "ERROR") in log
    assert any("Input Size 768 matches it (now 256" in t for t, _ in log)

    log.clear()  # prosplat's own .safetensors: no note
    prefs = type("P", (), {"weights_path": "/w/generator.safetensors", "max_input_size": 256})()
    preferences.draw_depthsplat_note(_Layout(log), prefs)
    assert log == []


def test_file_name_hints() -> None:
    h = depthsplat_file.hint("/x/depthsplat-gs-large-re10k-256x256-view2-e0f0f27a.pth")
    assert (h.model, h.depth_only, h.trained) == ("large", False, (256, 256))
    assert "non-commercial" in h.licence
    d = depthsplat_file.hint("depthsplat-depth-small-352x640-randview2-8-e807bd82.pth")
    assert d.depth_only and "depth only" in d.lines(256)[0]
    renamed = depthsplat_file.hint("my_finetune.pth")
    assert (
        renamed.model is None and "ViT-S" in renamed.licence and "CC-BY-NC-4.0" in renamed.licence
    )
    ft = depthsplat_file.hint("depthsplat-gs-small-re10k-256x256-view2-cfeab6b1-prosplat-ft.pth")
    assert ft.model == "small" and ft.trained == (256, 256)
    assert depthsplat_file.is_depthsplat_path("a/b.PTH") and not depthsplat_file.is_depthsplat_path(
        ""
    )
    assert not depthsplat_file.is_depthsplat_path("g.safetensors")
    from prosplat.pipeline.model import (
        DEPTHSPLAT_SUFFIXES,  # the worker routes by the same suffixes
    )

    assert depthsplat_file.SUFFIXES == DEPTHSPLAT_SUFFIXES
