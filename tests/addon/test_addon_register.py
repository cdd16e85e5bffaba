"""Packaging: register / unregister / register again, the preferences, and the built zip
installing as a real extension (Blender's own installer, in a throw-away user folder)."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

pytestmark = pytest.mark.blender
bpy = pytest.importorskip("bpy")

from addon_support import ROOT, addon, ensure_registered  # noqa: E402

sys.path.insert(0, str(ROOT / "scripts"))
import build_addon  # noqa: E402

OPERATORS = ("import_posed_images", "import_photos", "capture_inputs", "reconstruct",
             "render_view", "import_ply", "export_ply", "check_requirements",
             "install_requirements")  # fmt: skip


def _registered() -> dict[str, bool]:
    return {
        "scene_props": hasattr(bpy.types.Scene, "prosplat"),
        "panel": hasattr(bpy.types, "PROSPLAT_PT_main"),
        "prefs": addon.blender.preferences.ProSplatPreferences.is_registered,
        **{op: hasattr(bpy.types, f"PROSPLAT_OT_{op}") for op in OPERATORS},
    }


def test_register_unregister_register_again(blank) -> None:
    ensure_registered()
    assert all(_registered().values())
    addon.unregister()
    assert not any(_registered().values())
    addon.register()
    assert all(_registered().values())
    s = bpy.context.scene.prosplat
    assert (s.render_mode, s.save_raw, s.output_dir) == ("ACTIVE", False, "//prosplat_renders")
    # the File menus got exactly one entry each, even after re-registering
    funcs = [f.__name__ for f in bpy.types.TOPBAR_MT_file_import._dyn_ui_initialize()]
    assert funcs.count("menu_import") == 1


def test_preferences_default_without_enabling(blank) -> None:
    from addon.blender import runtime
    from addon.core import requirements

    p = runtime.prefs()
    assert (p.device, p.enhance, p.budget, p.python_path) == ("AUTO", True, 0, "")
    assert p.merge_flat is False  # opt-in: BENCHMARKS "Merging flat blocks"
    versions = requirements.requirement_versions()
    assert versions["numpy"] and "torch" in versions and "prosplat" in versions


def test_manifest_is_valid_and_checked() -> None:
    manifest = tomllib.loads((ROOT / "addon" / "blender_manifest.toml").read_text())
    build_addon.check_manifest(manifest)
    assert manifest["blender_version_min"] == "4.2.0" and manifest["id"] == "prosplat"
    bad = dict(manifest, tagline="x" * 70)
    with pytest.raises(ValueError, match="tagline"):
        build_addon.check_manifest(bad)
    with pytest.raises(ValueError, match="4.2"):
        build_addon.check_manifest(dict(manifest, blender_version_min="4.1.0"))


@pytest.fixture(scope="module")
def built_zip(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("dist")
    res = subprocess.run([sys.executable, str(ROOT / "scripts" / "build_addon.py"), "--out", str(out)],
                         capture_output=True, text=True)  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert "Blender validate: Success" in res.stdout
    return out / "prosplat-0.1.0.zip"


def test_zip_layout_and_reproducible(built_zip: Path, tmp_path: Path) -> None:
    with zipfile.ZipFile(built_zip) as zf:
        names = zf.namelist()
        manifest = tomllib.loads(zf.read("blender_manifest.toml").decode())
        wheel = zf.read("wheels/prosplat-0.1.0-py3-none-any.whl")
    # both layers' subfolders, with the root that registers them
    assert {"__init__.py", "blender/__init__.py", "blender/operators.py", "core/__init__.py",
            "core/jobs.py", "core/pins.py", "blender_manifest.toml", "README.md"} <= set(names)  # fmt: skip
    assert not any("__pycache__" in n for n in names)
    assert manifest["wheels"] == ["./wheels/prosplat-0.1.0-py3-none-any.whl"]
    (tmp_path / "w.whl").write_bytes(wheel)
    with zipfile.ZipFile(tmp_path / "w.whl") as wf:
        assert "prosplat/worker/__main__.py" in wf.namelist()
        # every file native.py compiles or includes: a missing one breaks the CPU renderer
        kernels = {"_cpu_kernels.cpp", "_cpu_project.cpp", "_cpu_parallel.h"}
        assert {f"prosplat/render/{k}" for k in kernels} <= set(wf.namelist())
    again = build_addon.build(tmp_path / "again")
    assert again.read_bytes() == built_zip.read_bytes()


_INSTALL = """
import sys, bpy, addon_utils
res = bpy.ops.extensions.package_install_files(filepath=sys.argv[-1], repo="user_default",
                                               enable_on_install=True)
name = "bl_ext.user_default.prosplat"
assert res == {"FINISHED"} and name in bpy.context.preferences.addons, res
assert hasattr(bpy.types.Scene, "prosplat") and hasattr(bpy.ops.prosplat, "reconstruct")
import prosplat.worker.tasks  # the bundled wheel imports
p = bpy.context.preferences.addons[name].preferences
assert (p.device, p.budget, p.merge_flat) == ("AUTO", 0, False)
addon_utils.disable(name)
assert not hasattr(bpy.types.Scene, "prosplat")
addon_utils.enable(name)
assert hasattr(bpy.types.Scene, "prosplat")
assert ".local" in prosplat.__file__, prosplat.__file__
print("INSTALLED", bpy.app.version_string, prosplat.__file__)
"""


def test_zip_installs_as_extension(built_zip: Path, tmp_path: Path) -> None:
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "user"))
    env.pop("PYTHONPATH", None)
    res = subprocess.run([sys.executable, "-c", _INSTALL, str(built_zip)], capture_output=True,
                         text=True, env=env, cwd=str(tmp_path), timeout=300)  # fmt: skip
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-3000:]
    assert "INSTALLED" in res.stdout


class _Layout:
    """A stand-in UILayout that checks what a panel asks for: every property exists on its
    data and every operator is registered (a typo would only show in the GUI otherwise)."""

    def __init__(self, log: list) -> None:
        self.log, self.enabled = log, True

    def prop(self, data, name, **kw) -> None:
        key = name[2:-2] if name.startswith('["') else None
        assert (key in data.keys()) if key else hasattr(data, name), name
        self.log.append(("prop", name))

    def operator(self, idname, **kw) -> None:
        group, op = idname.split(".")
        assert op in dir(getattr(bpy.ops, group)), idname
        self.log.append(("operator", idname))

    def label(self, **kw) -> None:
        self.log.append(("label", kw.get("text")))

    def progress(self, **kw) -> None:
        self.log.append(("progress", kw.get("text")))

    def _child(self, *a, **kw):
        return self

    def template_list(self, listtype, list_id, data, propname, active_data, active_prop, **kw):
        assert hasattr(bpy.types, listtype), listtype
        assert hasattr(data, propname) and hasattr(active_data, active_prop), propname
        self.log.append(("template_list", listtype))

    row = column = box = grid_flow = _child


def test_panels_and_menus_draw(blank, tmp_path: Path) -> None:
    from factories import random_gaussians

    from addon.blender import modal, preferences, ui
    from prosplat import write_ply

    write_ply(random_gaussians(10, 0), tmp_path / "g.ply")
    bpy.ops.prosplat.import_ply("EXEC_DEFAULT", filepath=str(tmp_path / "g.ply"))
    inputs = bpy.data.collections.new("inputs")
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    inputs.objects.link(cam)
    bpy.context.scene.prosplat.inputs = inputs
    log: list = []
    fake = type("Panel", (), {"layout": _Layout(log)})()
    modal.ACTIVE["reconstruct"] = type("D", (), {"job": type("J", (), {"progress": 0.5,
                                                                     "message": "x"})})()  # fmt: skip
    try:
        for cls in ui.CLASSES:
            if issubclass(cls, bpy.types.Panel):
                cls.draw(fake, bpy.context)
    finally:
        modal.ACTIVE.clear()
    ui.PROSPLAT_UL_views.draw_item(fake, bpy.context, fake.layout, inputs, cam, 0, None, "")
    assert ("template_list", "PROSPLAT_UL_views") in log and ("prop", "prosplat_use") in log
    ui.menu_import(fake, bpy.context)
    ui.menu_export(fake, bpy.context)
    prefs = type("Prefs", (), {"pip_args": "", "torch_build": "CPU"})()
    preferences.draw_requirements(_Layout(log), prefs)
    ops = {name for kind, name in log if kind == "operator"}
    assert {
        "prosplat.reconstruct",
        "prosplat.render_view",
        "prosplat.capture_inputs",
        "prosplat.import_ply",
        "prosplat.export_ply",
        "prosplat.install_requirements",
    } <= ops
    assert ("progress", "reconstruct: x") in log
    assert ("label", "10 Gaussians") in log
    import platform

    detected = [t for kind, t in log if kind == "label" and t and t.startswith("Detected: ")]
    assert detected == [f"Detected: {preferences.detected()}"]
    assert f"Blender {bpy.app.version_string}, Python {platform.python_version()}" in detected[0]


def test_pip_install_reports_progress_and_result() -> None:
    from addon.core import install

    cmd = install.pip_commands("/deps", "CPU", "--proxy URL")[
        -1
    ]  # tests/addon/test_addon_install.py
    assert cmd[1:5] == ["-m", "pip", "install", "--upgrade"] and "--proxy" in cmd
    assert cmd[cmd.index("--target") + 1] == "/deps"
    script = "print('Collecting torch'); print('Installing collected packages: torch'); "
    ok = install.PipInstall(
        [[sys.executable, "-c", script + "print('Successfully installed t-2')"]]
    )
    ok.start().wait()
    assert ok.poll() and ok.fraction == 1.0
    assert ok.summary()[0] and ok.summary()[1].startswith("installed 1 packages")
    fail = "import sys; print('ERROR: No matching distribution found for torch'); sys.exit(1)"
    bad = install.PipInstall([[sys.executable, "-c", fail]]).start()
    bad.wait()
    assert bad.summary() == (
        False,
        "pip failed (exit code 1): ERROR: No matching distribution found for torch",
    )
