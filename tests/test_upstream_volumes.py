"""
Mitsuba 3.9.1's own volume tests, ported onto nanovdbvolume and volpathlocal
(issue 23): a drop-in for gridvolume must pass them. Our words and code,
following the upstream tests' assertions and tolerances (dr.allclose's
defaults: rtol 1e-5, atol 1e-8):

- src/volumes/tests/test_grid.py      -> test_grid_* (gridvolume's unit tests)
- src/textures/tests/test_volume.py   -> test_volume_texture_*
- src/phase/tests/test_sggx.py        -> test_sggx_*
- src/render/tests/test_freeze.py     -> test_freeze_medium_* (test12, with our
                                         plugins in the heterogeneous medium)

Upstream writes .vol files and loads them by filename. nanovdbvolume reads
them too (made sparse at load), and the ports use both of gridvolume's other
inputs as well: a VolumeGrid read from the very .vol file (property "grid"),
and the tensor itself ("data"). Dense inputs clamp to their edge voxels by
default, as gridvolume does (wrap_mode "clamp"). Each test runs the upstream
assertion on gridvolume too (the control) and then on nanovdbvolume.
"""

import os

import pytest
import drjit as dr
import mitsuba as mi

from conftest import _setup_variant

PLUGINS = ["gridvolume", "nanovdbvolume"]



def load(plugin, grid, tmpdir, **kwargs):
    """The volume `plugin` on `grid` (a TensorXf): gridvolume from the .vol
    file as upstream does, nanovdbvolume from the VolumeGrid read back from
    that file."""
    path = os.path.join(str(tmpdir), "out.vol")
    mi.VolumeGrid(grid).write(path)
    if plugin == "gridvolume":
        return mi.load_dict({"type": "gridvolume", "filename": path, **kwargs})
    return mi.load_dict({"type": "nanovdbvolume", "grid": mi.VolumeGrid(path), **kwargs})


def rgb_variants():
    return [v for v in ["scalar_rgb", "llvm_ad_rgb"] if v in mi.variants()]


def all_variants():
    return [v for v in mi.variants() if not v.startswith("cuda")]


# ---------------------------------------------------------------------------
#  src/volumes/tests/test_grid.py
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("plugin", PLUGINS)
def test_grid_01_construct(plugin, tmpdir):
    _setup_variant("scalar_rgb")
    grid = dr.full(mi.TensorXf, 1, [4, 8, 16, 3]) * 1.5
    grid[..., 1] = 0.5
    grid[..., 2] = 0.0
    vol = load(plugin, grid, tmpdir)
    it = dr.zeros(mi.Interaction3f, 1)
    assert vol is not None
    assert dr.allclose(vol.eval(it), mi.Vector3f(1.5, 0.5, 0.0))


@pytest.mark.parametrize("plugin", PLUGINS)
@pytest.mark.parametrize("variant", all_variants())
def test_grid_02_nearest_interpolation(variant, plugin, tmpdir):
    _setup_variant(variant)
    grid = dr.full(mi.TensorXf, 1, [3, 3, 3])
    grid[0, 0, 0] = 0.0
    grid[1, 1, 1] = 0.5
    vol = load(plugin, grid, tmpdir, filter_type="nearest")
    it = dr.zeros(mi.Interaction3f, 1)
    assert dr.allclose(vol.eval(it), 0.0)
    it.p = mi.Point3f(1.0) * 1 / 6
    assert dr.allclose(vol.eval(it), 0.0)


@pytest.mark.parametrize("plugin", PLUGINS)
@pytest.mark.parametrize("variant", all_variants())
def test_grid_03_trilinear_interpolation(variant, plugin, tmpdir):
    _setup_variant(variant)
    grid = dr.full(mi.TensorXf, 1, [3, 3, 3])
    grid[0, 0, 0] = 0.0
    grid[1, 1, 1] = 0.5
    vol = load(plugin, grid, tmpdir)
    it = dr.zeros(mi.Interaction3f, 1)
    assert dr.allclose(vol.eval(it), 0.0)
    it.p = mi.Point3f(1.0) / 3
    assert dr.allclose(vol.eval(it), (6 * 1 + 1 * 0.5 + 1 * 0.0) / 8)


@pytest.mark.parametrize("plugin", PLUGINS)
@pytest.mark.parametrize("variant", all_variants())
def test_grid_04_trilinear_interpolation_boundary(variant, plugin, tmpdir):
    _setup_variant(variant)
    grid = dr.full(mi.TensorXf, 1, [3, 8, 5])
    grid[0, 0, 0] = 0.0
    grid[1, 1, 1] = 0.5
    grid[:, 7, :] = 0.55
    grid[0, :, :] = 0.32
    vol = load(plugin, grid, tmpdir)
    it = dr.zeros(mi.Interaction3f, 1)
    it.p = mi.Point3f(0.2, 1.0, 0.7)
    assert dr.allclose(vol.eval(it), 0.55)
    it.p = mi.Point3f(0.5, 0.5, 0.0)
    assert dr.allclose(vol.eval(it), 0.32)


@pytest.mark.parametrize("plugin", PLUGINS)
@pytest.mark.parametrize("variant", rgb_variants())
def test_grid_05_trilinear_interpolation_6_channels(variant, plugin, tmpdir):
    _setup_variant(variant)
    grid = dr.full(mi.TensorXf, 1, [3, 3, 3, 6])
    grid[0, 0, 0, :] = 0.0
    grid[1, 1, 1, :] = 0.5
    vol = load(plugin, grid, tmpdir)
    it = dr.zeros(mi.Interaction3f, 1)
    assert dr.allclose(vol.eval_6(it), 0.0)
    it.p = mi.Point3f(1.0) / 3
    assert dr.allclose(vol.eval_6(it), (6 * 1 + 1 * 0.5 + 1 * 0.0) / 8)


@pytest.mark.parametrize("plugin", PLUGINS)
@pytest.mark.parametrize("variant", rgb_variants())
def test_grid_06_eval_per_channel(variant, plugin, tmpdir):
    _setup_variant(variant)
    grid = dr.full(mi.TensorXf, 1, [3, 3, 3, 6])
    grid[0, 0, 0, :] = 0.0
    for i in range(6):
        grid[2, 2, 2, i] = i + 1
    vol = load(plugin, grid, tmpdir)
    it = dr.zeros(mi.Interaction3f, 1)
    assert dr.allclose(vol.eval_n(it), [0.0] * 6)
    it.p = mi.Point3f(1.0)
    assert dr.allclose(vol.eval_n(it), [1.0, 2.0, 3.0, 4.0, 5.0, 6.0])


# ---------------------------------------------------------------------------
#  src/textures/tests/test_volume.py (the `volume` texture around a volume)
# ---------------------------------------------------------------------------

def volume_texture(plugin, grid, tmpdir, tensor=False):
    if tensor:
        return mi.load_dict({"type": "volume", "volume": {"type": plugin, "data": grid}})
    path = os.path.join(str(tmpdir), "out.vol")
    mi.VolumeGrid(grid).write(path)
    inner = ({"type": "gridvolume", "filename": path} if plugin == "gridvolume"
             else {"type": "nanovdbvolume", "grid": mi.VolumeGrid(path)})
    return mi.load_dict({"type": "volume", "volume": inner})


def three_points():
    si = dr.zeros(mi.SurfaceInteraction3f)
    si.p = mi.Point3f([0.4, 0.4, 0.3], [0.5, 0.0, -0.5], [0.5, 0.4, 0.5])
    return si


@pytest.mark.parametrize("plugin", PLUGINS)
def test_volume_texture_01_eval(variant_llvm_ad_rgb, plugin, tmpdir):
    grid = dr.full(mi.TensorXf, 0.9, [3, 3, 3])
    grid[:, 0, :] = 0.0
    texture = volume_texture(plugin, grid, tmpdir)
    assert dr.allclose(dr.mean(texture.eval(three_points())), [0.9, 0.0, 0.0])
    assert dr.allclose(texture.max(), 0.9)


@pytest.mark.parametrize("plugin", PLUGINS)
def test_volume_texture_02_eval_1(variant_llvm_ad_rgb, plugin, tmpdir):
    grid = dr.full(mi.TensorXf, 0.9, [3, 3, 3])
    grid[:, 0, :] = 0.0
    texture = volume_texture(plugin, grid, tmpdir)
    assert dr.allclose(texture.eval_1(three_points()), [0.9, 0.0, 0.0])


@pytest.mark.parametrize("plugin", PLUGINS)
def test_volume_texture_03_eval_3(variant_llvm_ad_rgb, plugin, tmpdir):
    grid = dr.full(mi.TensorXf, 0.9, [3, 3, 3, 3])
    grid[..., 1] = 0.4
    grid[..., 2] = 0.2
    grid[:, 0, :, :] = 0.0
    texture = volume_texture(plugin, grid, tmpdir)
    ref = mi.Color3f([0.9, 0.0, 0.0], [0.4, 0.0, 0.0], [0.2, 0.0, 0.0])
    assert dr.allclose(texture.eval_3(three_points()), ref)
    assert dr.allclose(texture.max(), 0.9)


@pytest.mark.parametrize("plugin", PLUGINS)
def test_volume_texture_04_load_tensor(variant_llvm_ad_rgb, plugin, tmpdir):
    grid = dr.full(mi.TensorXf, 0.9, [3, 3, 3])
    grid[:, 0, :] = 0.0
    texture = volume_texture(plugin, grid, tmpdir, tensor=True)
    assert dr.allclose(dr.mean(texture.eval(three_points())), [0.9, 0.0, 0.0])
    assert dr.allclose(texture.max(), 0.9)


# ---------------------------------------------------------------------------
#  src/phase/tests/test_sggx.py (S: a 6-channel volume)
# ---------------------------------------------------------------------------

def sggx_volume(plugin, values, tmpdir):
    """S from a .vol file, as upstream (nanovdbvolume makes it sparse)"""
    path = os.path.join(str(tmpdir), "sggx.vol")
    mi.VolumeGrid(mi.TensorXf(values, (1, 1, 1, 6))).write(path)
    return {"type": plugin, "filename": path}


@pytest.mark.parametrize("plugin", PLUGINS)
def test_sggx_01_create(variant_scalar_rgb, plugin, tmpdir):
    p = mi.load_dict({"type": "sggx",
                      "S": sggx_volume(plugin, [1.0, 1.0, 1.0, 0.0, 0.0, 0.0], tmpdir)})
    assert p is not None
    assert p.flags() == mi.PhaseFunctionFlags.Anisotropic | mi.PhaseFunctionFlags.Microflake


@pytest.mark.parametrize("values", [[0.15, 1.0, 0.8, 0.0, 0.0, 0.0],
                                    [1.0, 0.35, 0.32, 0.52, 0.44, 0.2]],
                         ids=["02_chi2_simple", "03_chi2_skewed"])
@pytest.mark.parametrize("plugin", PLUGINS)
def test_sggx_chi2(variant_llvm_ad_rgb, plugin, values, tmpdir):
    from mitsuba.chi2 import ChiSquareTest, PhaseFunctionAdapter, SphericalDomain
    path = os.path.join(str(tmpdir), "sggx.vol")
    mi.VolumeGrid(mi.TensorXf(values, (1, 1, 1, 6))).write(path)
    # nanovdbvolume reads gridvolume's .vol files too (made sparse at load)
    xml = f'<volume type="{plugin}" name="S"><string name="filename" value="{path}"/></volume>'
    sample_func, pdf_func = PhaseFunctionAdapter("sggx", xml)
    chi2 = ChiSquareTest(domain=SphericalDomain(), sample_func=sample_func, pdf_func=pdf_func,
                         sample_dim=3)
    assert chi2.run()


# ---------------------------------------------------------------------------
#  src/render/tests/test_freeze.py, test12_medium (heterogeneous)
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("auto_opaque", [False, True])
@pytest.mark.parametrize("integrator", ["volpath", "volpathlocal"])
@pytest.mark.parametrize("plugin", PLUGINS)
def test_freeze_medium(variant_llvm_ad_rgb, plugin, integrator, auto_opaque):
    # The cornell box seen through a heterogeneous medium (the albedo grid
    # of the participating_media scenes as a 3-channel extinction), rendered
    # 5 times by a frozen function: equal to the unfrozen renders, 2
    # recordings
    import mitsuba_media_scenes as ms
    w, h, n, spp = 16, 16, 5, 1
    scene = mi.cornell_box()
    scene["sensor"]["film"]["width"] = w
    scene["sensor"]["film"]["height"] = h
    scene["integrator"] = {"type": integrator}
    scene["sensor"]["medium"] = {
        "type": "heterogeneous",
        "albedo": {"type": "rgb", "value": [0.99, 0.9, 0.96]},
        "sigma_t": {"type": plugin, "data": mi.TensorXf(ms.albedo_values())},
    }
    scene = mi.load_dict(scene, parallel=True)

    def func(scene):
        return mi.render(scene, spp=spp)

    frozen = dr.freeze(func, auto_opaque=auto_opaque)
    for i in range(n):
        res = frozen(scene)
        ref = func(scene)
        assert dr.allclose(ref, res)
    assert frozen.n_recordings == 2
