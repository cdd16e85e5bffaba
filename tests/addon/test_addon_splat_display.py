"""How Gaussian objects look in Blender (issue 15): oriented ellipsoids with the Gaussians'
rotation and scale, an opacity-aware material whose colours render in Cycles and EEVEE (also
after saving and reloading the .blend), hidden from final renders by default, a viewport point
budget, PLY warnings in the import report, and the native-splat attribute conversion.

Renders are 32x32 with few samples, read back as linear EXR; the scene has no world, so the
background is black and a splat's pixels are its emission.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
import torch

pytestmark = pytest.mark.blender
bpy = pytest.importorskip("bpy")

from addon_support import data_counts, evaluated_instances, run_op  # noqa: E402

from addon.blender import native_splats, pointcloud, runtime, splat_display, steps  # noqa: E402
from addon.core import splat_math  # noqa: E402
from prosplat import Gaussians, read_ply, write_ply  # noqa: E402
from prosplat.convert.pointcloud import to_attributes  # noqa: E402
from prosplat.core.gaussians import SH_C0, rgb_to_sh0  # noqa: E402
from prosplat.render.projection import quat_to_rotmat  # noqa: E402

SIZE = 32
TIMINGS: dict[str, float] = {}


# ---- helpers ----------------------------------------------------------------------------------
def _splats(means, rgb, scales=None, quats=None, opacity=0.99) -> Gaussians:
    means = torch.as_tensor(means, dtype=torch.float32).reshape(-1, 3)
    n = means.shape[0]
    rgb = torch.as_tensor(rgb, dtype=torch.float32).reshape(n, 3)
    scales = torch.full((n, 3), 0.15) if scales is None else torch.as_tensor(scales).float()
    quats = torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1) if quats is None else quats.float()
    sh = rgb_to_sh0(rgb).reshape(n, 1, 3)
    opacities = torch.as_tensor(opacity, dtype=torch.float32).expand(n).clone()
    return Gaussians(means, quats, scales, opacities, sh)


RED_GREEN = _splats([[-0.8, 0.0, 0.0], [0.8, 0.0, 0.0]], [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def _generated(g: Gaussians, name: str = "Generated"):
    """The object a reconstruction makes (the worker's arrays -> steps.apply_gaussians):
    Blender's own splats where this Blender has them, else the mesh display."""
    return steps.apply_gaussians({"arrays": to_attributes(g)}, name, bpy.context.scene.collection)


def _mesh(g: Gaussians, name: str = "Mesh"):
    """The mesh + Geometry Nodes display (the only one before 5.3, the fallback after)."""
    return pointcloud.create_object(name, to_attributes(g), bpy.context.scene.collection,
                                    native=False)  # fmt: skip


#: The displays this Blender has: the mesh everywhere, Blender's own splats on 5.3+.
DISPLAYS = ["mesh", "native"] if native_splats.supported() else ["mesh"]


def _made(g: Gaussians, display: str):
    obj = _mesh(g) if display == "mesh" else _generated(g)
    assert (obj.type == "MESH") == (display == "mesh")
    return obj


def _imported(g: Gaussians, tmp_path: Path):
    write_ply(g, tmp_path / "splats.ply")
    res, err = run_op(bpy.ops.prosplat.import_ply, filepath=str(tmp_path / "splats.ply"))
    assert res == {"FINISHED"}, err
    return bpy.context.scene.prosplat.gaussians


def _camera(scene) -> None:
    """Looking down -Z from z = 5: world x is image columns, a 50 mm lens sees x in +-1.8."""
    cam = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    scene.collection.objects.link(cam)
    cam.location = (0.0, 0.0, 5.0)
    scene.camera = cam
    scene.render.resolution_x = scene.render.resolution_y = SIZE
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.world = None


def _render(engine: str, tmp_path: Path, tag: str) -> np.ndarray:
    """F12 with ``engine``; returns [H, W, 4] linear RGBA (row 0 at the bottom)."""
    scene = bpy.context.scene
    scene.render.engine = engine
    if engine == "CYCLES":
        scene.cycles.device = "CPU"
        scene.cycles.samples = 8
        scene.cycles.use_denoising = False
    else:
        scene.eevee.taa_render_samples = 8
    scene.render.filepath = str(tmp_path / f"{tag}.exr")
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    TIMINGS[tag] = time.perf_counter() - t0
    print(f"\n{tag}: {engine} {SIZE}x{SIZE} render {TIMINGS[tag]:.2f} s")
    img = bpy.data.images.load(scene.render.filepath)
    try:
        return np.array(img.pixels[:], dtype=np.float32).reshape(SIZE, SIZE, 4)
    finally:
        bpy.data.images.remove(img)


def _column_colour(px: np.ndarray, x: float) -> np.ndarray:
    """Mean RGB of the 3x3 pixels around world (x, 0) in the _camera view."""
    col = int(round(SIZE / 2 + x / 1.8 * SIZE / 2 - 0.5))
    return px[SIZE // 2 - 2 : SIZE // 2 + 1, col - 1 : col + 2, :3].reshape(-1, 3).mean(axis=0)


def _assert_red_and_green(px: np.ndarray) -> None:
    red, green = _column_colour(px, -0.8), _column_colour(px, 0.8)
    assert red[0] > 0.25 and red[1] < 0.03 and red[2] < 0.03, f"red splat renders {red}"
    assert green[1] > 0.25 and green[0] < 0.03 and green[2] < 0.03, f"green splat renders {green}"
    assert px[:, SIZE // 2 - 1 : SIZE // 2 + 1, :3].max() < 0.02, "the gap between them is lit"


def _save_and_reload(tmp_path: Path) -> None:
    path = str(tmp_path / "scene.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)


def _input(obj, name: str, value) -> None:
    splat_display.set_input(obj.modifiers[splat_display.MODIFIER], name, value)


# ---- shape -----------------------------------------------------------------------------------
def test_instances_follow_quaternion_and_scale(blank) -> None:
    """Each instance is R(q) diag(Sigma exp(scale)) at the mean, R from the rasterizer's own
    quaternion convention (w, x, y, z; not normalised in the file)."""
    gen = torch.Generator().manual_seed(3)
    n = 6
    quats = torch.randn(n, 4, generator=gen) * 2
    scales = torch.tensor([0.30, 0.08, 0.02]).repeat(n, 1) * torch.rand(n, 1, generator=gen)
    means = torch.arange(n, dtype=torch.float32)[:, None] * torch.tensor([1.0, 0.5, -0.25])
    g = _splats(means, torch.rand(n, 3, generator=gen), scales, quats)
    obj = _mesh(g)
    _input(obj, splat_display.MAX_SIZE_SOCKET, 10.0)
    _input(obj, splat_display.SIGMA_SOCKET, 2.5)
    mats = evaluated_instances(obj)
    assert len(mats) == n
    R = quat_to_rotmat(quats / quats.norm(dim=1, keepdim=True)).numpy()  # [N, 3, 3]
    for m in mats:
        i = int(np.argmin(np.linalg.norm(means.numpy() - m[:3, 3], axis=1)))
        np.testing.assert_allclose(m[:3, 3], means[i].numpy(), atol=1e-6)
        want = R[i] * (2.5 * scales[i].numpy())[None, :]  # columns: the scaled local axes
        np.testing.assert_allclose(m[:3, :3], want, atol=1e-5 * float(scales[i].max()) + 1e-7)


def test_max_size_clamps_far_splats(blank) -> None:
    """A 14-unit far splat is drawn at most Max Size; the default comes from the cloud."""
    gen = torch.Generator().manual_seed(0)
    means = torch.rand(400, 3, generator=gen) * 4
    scales = (0.005 + 0.005 * torch.rand(400, 1, generator=gen)).repeat(1, 3)
    scales[0] = torch.tensor([7.0, 7.0, 0.001])  # the far ground splat (a flat disc)
    obj = _mesh(_splats(means, torch.rand(400, 3, generator=gen), scales))
    mod = obj.modifiers[splat_display.MODIFIER]
    max_size = splat_display.get_input(mod, "Max Size")
    want = float(np.percentile(2 * scales.max(dim=1).values.double().numpy(), 99))
    assert max_size == pytest.approx(want, rel=1e-6)  # p99 of 2 sigma (under 2% of the extent)
    mats = evaluated_instances(obj)
    axes = np.array([np.linalg.norm(m[:3, :3], axis=0) for m in mats])  # [N, 3] semi-axes
    assert axes.max() <= max_size * (1 + 1e-5)
    big = int(
        np.argmin(np.linalg.norm(np.array([m[:3, 3] for m in mats]) - means[0].numpy(), axis=1))
    )
    np.testing.assert_allclose(axes[big], [max_size, max_size, 0.002], rtol=1e-5)
    small = np.sort(axes[:, 0])[: len(axes) // 2]  # ordinary splats are not clamped
    np.testing.assert_allclose(small, np.sort(2 * scales[1:, 0].numpy())[: len(small)], rtol=1e-5)


def test_viewport_budget_bounds_the_count(blank) -> None:
    g = _splats(torch.randn(5000, 3), torch.rand(5000, 3))
    obj = _mesh(g)
    _input(obj, splat_display.VIEWPORT_SOCKET, 300)
    assert len(evaluated_instances(obj)) == 300
    _input(obj, splat_display.VIEWPORT_SOCKET, 0)  # 0: all
    assert len(evaluated_instances(obj)) == 5000
    _input(obj, splat_display.VIEWPORT_SOCKET, 10_000)  # more than there are
    assert len(evaluated_instances(obj)) == 5000


# ---- renders ---------------------------------------------------------------------------------
@pytest.mark.parametrize("display", DISPLAYS)
@pytest.mark.parametrize("source", ["ply", "generated"])
def test_cycles_shows_splat_colours_also_after_reload(blank, tmp_path: Path, source, display):
    if source == "ply":
        obj = _imported(RED_GREEN, tmp_path)  # the default display: native on 5.3+
        if display == "mesh":
            pytest.skip("Import Gaussian PLY makes the default display; the mesh is 'generated'")
    else:
        obj = _made(RED_GREEN, display)
    obj.hide_render = False
    _camera(blank)
    _assert_red_and_green(_render("CYCLES", tmp_path, f"cycles-{source}"))
    _save_and_reload(tmp_path)
    _assert_red_and_green(_render("CYCLES", tmp_path, f"cycles-{source}-reloaded"))


@pytest.mark.parametrize("display", DISPLAYS)
def test_eevee_shows_splat_colours_also_after_reload(blank, tmp_path: Path, display) -> None:
    """EEVEE renders headless here (software OpenGL through EGL), so it is rendered for real."""
    obj = _imported(RED_GREEN, tmp_path) if display != "mesh" else _mesh(RED_GREEN)
    obj.hide_render = False
    _camera(blank)
    _assert_red_and_green(_render("BLENDER_EEVEE", tmp_path, "eevee"))
    _save_and_reload(tmp_path)
    _assert_red_and_green(_render("BLENDER_EEVEE", tmp_path, "eevee-reloaded"))


@pytest.mark.parametrize("display", DISPLAYS)
def test_opacity_and_falloff_shape_the_splat(blank, tmp_path: Path, display) -> None:
    """A faint splat renders fainter, and every splat fades from its centre outwards."""
    g = _splats([[-0.8, 0, 0], [0.8, 0, 0]], [[1.0, 0, 0], [1.0, 0, 0]], opacity=[0.95, 0.3])
    _made(g, display).hide_render = False
    _camera(blank)
    px = _render("CYCLES", tmp_path, "cycles-opacity")
    a, b = _column_colour(px, -0.8)[0], _column_colour(px, 0.8)[0]
    assert 0.2 < b / a < 0.45, (a, b)  # about 0.3 / 0.95
    row = px[SIZE // 2 - 1, :, 0]
    centre = int(round(SIZE / 2 - 0.8 / 1.8 * SIZE / 2 - 0.5))
    assert row[centre] > row[centre - 2] > row[centre - 4]  # a falloff, not a solid disc


@pytest.mark.parametrize("display", DISPLAYS)
def test_cloud_is_not_in_f12_renders_unless_asked(blank, tmp_path: Path, display) -> None:
    obj = _imported(RED_GREEN, tmp_path) if display != "mesh" else _mesh(RED_GREEN)
    assert obj.hide_render, "new Gaussian objects are hidden from final renders"
    _camera(blank)
    assert _render("CYCLES", tmp_path, "hidden")[..., :3].max() < 1e-3
    obj.hide_render = False  # the panel's "Show in Renders"
    _assert_red_and_green(_render("CYCLES", tmp_path, "shown"))


def test_viewport_budget_leaves_renders_whole(blank, tmp_path: Path) -> None:
    obj = _mesh(RED_GREEN)
    obj.hide_render = False
    _input(obj, splat_display.VIEWPORT_SOCKET, 1)
    assert len(evaluated_instances(obj)) == 1
    _camera(blank)
    _assert_red_and_green(_render("CYCLES", tmp_path, "cycles-budget"))


@pytest.mark.parametrize("name", ["color", pointcloud.COLOR_ATTR])
def test_cycles_reads_a_geometry_attribute_called_color_as_black(blank, tmp_path, name) -> None:
    """The cause of the black clouds, on the old display (Mesh to Points + an Attribute node
    of type Geometry): Cycles takes the attribute name ``color`` for its volume colour
    (``ATTR_STD_VOLUME_COLOR``), so the node got 0 whether the file was fresh or reloaded.
    Any other name renders; the display also reads the colour as an instance attribute."""
    mesh = bpy.data.meshes.new("Old")
    mesh.vertices.add(1)
    mesh.vertices.foreach_set("co", [-0.8, 0.0, 0.0])
    mesh.color_attributes.new(name, "FLOAT_COLOR", "POINT").data[0].color = (1, 0, 0, 1)
    mat = bpy.data.materials.new("Old")
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    attr = nodes.new("ShaderNodeAttribute")
    attr.attribute_type, attr.attribute_name = "GEOMETRY", name
    emit, out = nodes.new("ShaderNodeEmission"), nodes.new("ShaderNodeOutputMaterial")
    links.new(attr.outputs["Color"], emit.inputs["Color"])
    links.new(emit.outputs[0], out.inputs["Surface"])
    tree = bpy.data.node_groups.new("Old", "GeometryNodeTree")
    tree.interface.new_socket(name="Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket(name="Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gin, gout = tree.nodes.new("NodeGroupInput"), tree.nodes.new("NodeGroupOutput")
    to_points, set_mat = (
        tree.nodes.new("GeometryNodeMeshToPoints"),
        tree.nodes.new("GeometryNodeSetMaterial"),
    )
    to_points.inputs["Radius"].default_value = 0.3
    set_mat.inputs["Material"].default_value = mat
    tree.links.new(gin.outputs[0], to_points.inputs["Mesh"])
    tree.links.new(to_points.outputs[0], set_mat.inputs["Geometry"])
    tree.links.new(set_mat.outputs[0], gout.inputs[0])
    obj = bpy.data.objects.new("Old", mesh)
    obj.modifiers.new("Old", "NODES").node_group = tree
    blank.collection.objects.link(obj)
    _camera(blank)
    red = _column_colour(_render("CYCLES", tmp_path, f"cycles-old-{name}"), -0.8)
    if name != "color":
        assert red[0] > 0.25, red
    elif red[0] > 0.25:
        pytest.skip("this Cycles reads 'color' as a plain attribute; the rename is harmless")
    else:
        assert red.max() < 0.03


# ---- PLY import reports ----------------------------------------------------------------------
def test_import_reports_dropped_ply_properties(blank, tmp_path: Path) -> None:
    from plyfile import PlyData, PlyElement

    write_ply(RED_GREEN, tmp_path / "plain.ply")
    vertex = PlyData.read(str(tmp_path / "plain.ply"))["vertex"].data
    transform = np.zeros(1, dtype=[("transform", "f4")])
    PlyData([PlyElement.describe(vertex, "vertex"),
             PlyElement.describe(transform, "transform")]).write(str(tmp_path / "super.ply"))  # fmt: skip
    result = runtime.run_sync(*steps.import_ply_job(str(tmp_path / "super.ply")))
    assert result["warnings"] == [
        "super.ply: dropped elements transform (not part of a 3DGS Gaussian)"
    ]
    res, err = run_op(bpy.ops.prosplat.import_ply, filepath=str(tmp_path / "super.ply"))
    assert res == {"FINISHED"}, err


def test_zero_point_ply_is_refused(blank, tmp_path: Path) -> None:
    write_ply(Gaussians.empty(sh_degree=1), tmp_path / "empty.ply")
    before = data_counts()
    res, err = run_op(bpy.ops.prosplat.import_ply, filepath=str(tmp_path / "empty.ply"))
    assert res == {"CANCELLED"} and "holds 0 Gaussians" in err
    assert data_counts() == before


# ---- display maths and the native (Blender 5.3) layout ----------------------------------------
def test_default_max_size_ignores_outliers() -> None:
    rng = np.random.default_rng(0)
    pos = rng.uniform(0, 10, (1000, 3))
    logs = np.full((1000, 3), np.log(0.05))
    logs[:5] = np.log(7.0)  # five huge far splats
    size = splat_math.default_max_size(pos, logs, sigma=2.0)
    assert size == pytest.approx(0.1)  # p99 of 2 x 0.05: five outliers do not set it
    logs[:50] = np.log(7.0)  # 5% huge: p99 is huge, so the ceiling applies
    extent = np.linalg.norm(np.percentile(pos, 99, 0) - np.percentile(pos, 1, 0))  # ~17
    assert splat_math.default_max_size(pos, logs) == pytest.approx(max(1.0, 0.02 * extent))
    logs[:] = np.log(7.0)  # all alike: drawn as they are
    assert splat_math.default_max_size(pos, logs) == pytest.approx(14.0)
    assert splat_math.default_max_size(np.zeros((0, 3)), np.zeros((0, 3))) == 1.0
    assert splat_math.default_max_size(np.zeros((1, 3)), np.full((1, 3), -1.0)) > 0


@pytest.mark.parametrize("degree", [0, 2, 3])
def test_native_attributes_match_the_gaussians(tmp_path: Path, degree: int) -> None:
    """Our PLY attributes -> Blender 5.3's GAUSSIAN_SPLAT layout (checked against Blender's
    own importer in test_addon_native_splats.py) and back, exactly."""
    from factories import random_gaussians

    write_ply(random_gaussians(50, degree, seed=degree), tmp_path / "g.ply")
    g = read_ply(tmp_path / "g.ply", dtype=torch.float64)
    arrays = to_attributes(g)
    out = splat_math.native_attributes(arrays)
    assert splat_math.SH_C0 == SH_C0
    q = g.quats / g.quats.norm(dim=1, keepdim=True)
    np.testing.assert_allclose(out["rotation"], q.numpy(), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(out["scale"], g.scales.numpy(), rtol=1e-6)
    base = out[splat_math.NATIVE_BASE]  # [N, 4]: the raw DC coefficients and linear opacity
    np.testing.assert_allclose(base[:, 3], g.opacities.numpy(), rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(base[:, :3], g.sh[:, 0].float().numpy())
    k = (degree + 1) ** 2
    sh_names = [splat_math.native_sh_name(j) for j in range(k - 1)]
    assert sorted(out) == sorted(["position", "rotation", "scale", "radiance:base", *sh_names])
    for j in range(1, k):
        np.testing.assert_array_equal(out[f"radiance:sh_{j - 1}"], g.sh[:, j].float().numpy())
    zero = splat_math.native_attributes(
        {**arrays, **{f"rot_{i}": np.zeros(50, np.float32) for i in range(4)}}
    )
    np.testing.assert_array_equal(zero["rotation"], np.tile([1, 0, 0, 0], (50, 1)))

    exact = {name: arrays[name] for name in splat_math.EXACT_NAMES}
    back = splat_math.ply_attributes(out, exact)  # a cloud made here: bit for bit
    assert sorted(back) == sorted(k for k in arrays if k != "color")
    for name, values in back.items():
        np.testing.assert_array_equal(values, arrays[name], err_msg=name)
    decoded = splat_math.ply_attributes(out)  # Blender's own import: decoded, not exact
    np.testing.assert_allclose(decoded["opacity"], arrays["opacity"], rtol=1e-4, atol=1e-4)
    for i in range(3):
        np.testing.assert_allclose(decoded[f"scale_{i}"], arrays[f"scale_{i}"], atol=1e-6)
    np.testing.assert_allclose(np.stack([decoded[f"rot_{i}"] for i in range(4)], 1), q.numpy(),
                               atol=1e-6)  # fmt: skip


def test_native_values_an_artist_edited_win_over_the_kept_ones() -> None:
    """Where a point's native value no longer agrees with the PLY value kept beside it (an
    edit in Blender), export takes the native one for that point only."""
    arrays = {"position": np.zeros((3, 3), np.float32), "opacity": np.zeros(3, np.float32),
              **{f"scale_{i}": np.full(3, -2.0, np.float32) for i in range(3)},
              **{f"rot_{i}": np.full(3, 2.0, np.float32) for i in range(4)},
              **{f"f_dc_{i}": np.ones(3, np.float32) for i in range(3)}}  # fmt: skip
    native = splat_math.native_attributes(arrays)
    native["scale"][1] = [1.0, 2.0, 3.0]
    native["radiance:base"][2, 3] = 0.9
    exact = {k: arrays[k] for k in splat_math.EXACT_NAMES}
    back = splat_math.ply_attributes(native, exact)
    np.testing.assert_array_equal(back["scale_0"][[0, 2]], [-2.0, -2.0])
    np.testing.assert_allclose([back[f"scale_{i}"][1] for i in range(3)], np.log([1, 2, 3]),
                               atol=1e-6)  # fmt: skip
    np.testing.assert_array_equal(back["opacity"][:2], [0.0, 0.0])
    assert back["opacity"][2] == pytest.approx(np.log(9.0), rel=1e-5)
    np.testing.assert_array_equal(back["rot_0"], [2.0, 2.0, 2.0])  # unit quaternion unchanged


@pytest.mark.parametrize("display", DISPLAYS)
def test_panel_rows_resolve(blank, display) -> None:
    """The Gaussians panel shows Sigma, Max Size, Viewport Points (the mesh display's inputs,
    through this Blender's modifier API) and Show in Renders."""
    obj = _made(RED_GREEN, display)
    rows: list[tuple[str, object]] = []

    class Layout:
        def prop(self, data, path, text="", **kw):
            rows.append((text, data.path_resolve(path)))

        def label(self, text="", **kw):
            rows.append((text, None))

    splat_display.draw_settings(Layout(), obj)
    texts = [t for t, _ in rows]
    if display == "mesh":
        assert texts == [*splat_display.SOCKETS, "Show in Renders", "2 Gaussians"]
        assert dict(rows)[splat_display.MAX_SIZE_SOCKET] == pytest.approx(
            splat_display.get_input(obj.modifiers[splat_display.MODIFIER], "Max Size")
        )
    else:
        assert texts == ["Show in Renders", "2 Gaussians", "Drawn as Blender's own Gaussian splats"]
    assert dict(rows)["Show in Renders"] is True  # hide_render (the checkbox is inverted)
