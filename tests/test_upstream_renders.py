"""
Mitsuba 3.9.1's participating-media render tests (src/render/tests/
test_renders.py on mitsuba-data's tests/scenes/participating_media), ported
onto nanovdbvolume and volpathlocal (issue 23).

The scenes are rebuilt in tests/mitsuba_media_scenes.py (their data cannot
be shipped), so the upstream reference images do not apply: the reference
of each scene is rendered here, once per session, by the scene's own
integrator (volpath, or volpathmis where the file says so) with gridvolume,
on llvm_ad_rgb at REF_SPP samples per pixel. Each candidate replaces
gridvolume by nanovdbvolume on the same data (gridvolume's edge convention:
wrap_mode "clamp", the default for dense data) and the integrator by
volpathlocal, with tracking forced (max_majorant_ratio 1) and at its
defaults; Mitsuba's volpath and volpathmis on nanovdbvolume are candidates
too.

The statistic is upstream's: a per-pixel two-sided z-test in XYZ, at a
significance of 0.01 with Sidak's correction for the number of pixels, and
the image passes if at least 99.75 % of the pixel channels pass. Upstream
tests against a reference with a known variance image; both sides here are
Monte Carlo estimates, so the variance of the difference is the sum of the
two (each from Mitsuba's `moment` integrator: the second moment per pixel).
"""

import math

import numpy as np
import pytest
import drjit as dr
import mitsuba as mi

import mitsuba_media_scenes as ms
from conftest import _setup_variant

REF_SPP = 1024
SPP = {"llvm_ad_rgb": 256, "scalar_rgb": 128}
GRID_SCENES = ["hetero_sigmat", "hetero_sigmat_albedo", "hetero_spectral_sigmat"]


def moments(scene_dict, spp, seed):
    """(mean, per-sample variance) per pixel, XYZ, through the moment integrator"""
    d = dict(scene_dict)
    d["integrator"] = {"type": "moment", "inner": d["integrator"]}
    scene = mi.load_dict(d)
    scene.integrator().render(scene, seed=seed, spp=spp)
    parts = dict(scene.sensors()[0].film().bitmap(raw=False).split())
    m1 = np.array(parts["inner"], dtype=np.float64)
    m2 = np.array(parts["m2_inner"], dtype=np.float64)
    assert np.all(np.isfinite(m1)) and np.all(np.isfinite(m2)), "NaN or Inf in a pixel"
    return m1, np.maximum(m2 - m1 * m1, 0.0), scene


@pytest.fixture(scope="module")
def references(tmp_path_factory):
    """The reference of each scene: the scene's integrator with gridvolume
    (llvm_ad_rgb, REF_SPP), rendered on first use"""
    directory = tmp_path_factory.mktemp("mitsuba_media")
    cache = {}

    def get(name):
        if name not in cache:
            _setup_variant("llvm_ad_rgb")
            d = ms.scene(name, directory, ms.SCENE_INTEGRATOR[name], plugin="gridvolume",
                         spp=REF_SPP)
            m, v, _ = moments(d, REF_SPP, seed=1000)
            cache[name] = (m, v)
        return cache[name], directory
    return get


def z_test(a, var_a, n_a, b, var_b, n_b):
    """Upstream's acceptance: the fraction of pixel channels whose two-sided
    p-value exceeds the Sidak-corrected significance, and that bound"""
    # Upstream floors the reference variance at 1e-4 (per sample)
    var = np.maximum(var_a, 1e-4) / n_a + np.maximum(var_b, 1e-4) / n_b
    z = np.abs(a - b) / np.sqrt(var)
    p = np.vectorize(lambda x: math.erfc(x / math.sqrt(2)))(z)
    pixels = a.shape[0] * a.shape[1]
    alpha = 1.0 - (1.0 - 0.01) ** (1.0 / pixels)
    return (p > alpha).mean(), alpha


# Different by design: volpath's estimator (which volpathlocal keeps for
# every medium it does not track, here a homogeneous one) against a medium
# whose extinction varies fivefold across channels (1, 0.2, 1) x 10: its
# weights are heavy-tailed and 256 samples per pixel do not reach the normal
# regime the z-test assumes. Mitsuba renders this scene with volpathmis, and
# its own volpath fails the same test (measured: 97.7 % of the pixel
# channels pass, 99.75 % required).
SPECTRAL_BY_DESIGN = pytest.mark.xfail(
    strict=True, reason="volpath's estimator on a strongly spectral medium: the scene's own "
                        "integrator is volpathmis; stock volpath fails it too")


def mark(scene, integrator):
    return [SPECTRAL_BY_DESIGN] if scene == "homo_spectral_sigmat" and \
        integrator in ("volpath", "volpathlocal") else []


CANDIDATES = (
    [pytest.param(s, "volpathlocal", {"max_majorant_ratio": 1.0}, id=f"{s}-volpathlocal-forced",
                  marks=mark(s, "volpathlocal")) for s in ms.SCENES] +
    [pytest.param(s, "volpathlocal", {}, id=f"{s}-volpathlocal-default") for s in GRID_SCENES] +
    [pytest.param(s, i, {}, id=f"{s}-{i}") for s in GRID_SCENES for i in ("volpath", "volpathmis")] +
    [pytest.param("homo_spectral_sigmat", "volpath", {}, id="homo_spectral_sigmat-volpath",
                  marks=mark("homo_spectral_sigmat", "volpath"))]
)


def in_scalar(param):
    """Which candidates run in scalar_rgb as well: volpathlocal on every
    scene (Mitsuba's own integrators on nanovdbvolume: llvm_ad_rgb only).
    At 64 spp instead of 128, three scenes fail the z-test (heavy-tailed
    weights; bench/PERF_LOG.md 29)."""
    name, integrator, _ = param.values
    return integrator == "volpathlocal"


@pytest.mark.slow
@pytest.mark.parametrize("variant, name, integrator, args",
    [pytest.param("scalar_rgb", *p.values, id=f"{p.id}-scalar_rgb", marks=p.marks)
     for p in CANDIDATES if in_scalar(p)] +
    [pytest.param("llvm_ad_rgb", *p.values, id=f"{p.id}-llvm_ad_rgb", marks=p.marks)
     for p in CANDIDATES])
def test_render(references, variant, name, integrator, args):
    (ref, ref_var), directory = references(name)
    _setup_variant(variant)
    spp = SPP[variant]
    depth = 16 if name in ("homo_dielectric_envmap", "homo_roughdielectric_spot") else 6
    d = ms.scene(name, directory, {"type": integrator, "max_depth": depth, **args},
                 plugin="nanovdbvolume", spp=spp)
    img, var, scene = moments(d, spp, seed=7)
    if integrator == "volpathlocal" and args and name in GRID_SCENES:
        params = mi.traverse(scene.integrator())  # (the moment integrator's "inner")
        assert [int(params[k]) for k in params.keys() if k.endswith("tracked_media")] == [1]
    passed, alpha = z_test(img, var, spp, ref, ref_var, REF_SPP)
    print(f"{name} {integrator} {args} {variant}: {passed:.5f} of the pixel channels "
          f"pass (alpha {alpha:.2e}); means {img.mean(axis=(0, 1))} vs {ref.mean(axis=(0, 1))}")
    assert passed >= 0.9975, (passed, img.mean(axis=(0, 1)), ref.mean(axis=(0, 1)))
