"""
What only a GPU can check: the grid's footprint in device memory, and CUDA
lookups against the LLVM ones on the same points. Skipped (with the reason)
on machines without a CUDA device; `scripts/gpu_kit_run.sh` runs them on one.

The rest of the suite covers cuda_ad_* through its variant fixtures
(`variants_rgb`, `variants_all`, or NVDB_TEST_VARIANTS).
"""

import subprocess

import numpy as np
import pytest
import drjit as dr

from conftest import (BUILD, _setup_variant, eval_points, gpu_used_bytes, has_llvm, load_nvdb,
                      settle_gpu)

BIG = BUILD / "bin" / "nvdb_big_grid"


def setup_cuda():
    _setup_variant("cuda_ad_rgb")
    if gpu_used_bytes() is None:
        pytest.skip("neither pynvml nor nvidia-smi can read the GPU's memory")


def warm_up(path):
    """The first CUDA work loads modules and creates the context: do it before
    any memory reading."""
    v = eval_points(load_nvdb(path, filter_type="nearest"), np.full((16, 3), 0.5, np.float32))
    assert np.all(np.isfinite(v))
    settle_gpu()


def test01_device_holds_the_grid_at_its_size(tmp_path, make_grid):
    # A 1.0 GB grid: NVML's "used" grows by the grid's size (<= 1.01x; the
    # driver maps device memory in 2 MiB pages), Dr.Jit's own accounting of
    # the volume's storage says the same, and everything is returned when
    # the volume dies. Dr.Jit's jit_malloc would have taken 2^30 B, 1.07x.
    setup_cuda()
    path = tmp_path / "g.nvdb"
    out = subprocess.run([str(BIG), "write", str(path), "470000"], check=True,
                         capture_output=True, text=True).stdout.split()
    size = int(out[1])
    assert size == path.stat().st_size
    small, _ = make_grid("single_voxel", dense=False)
    warm_up(small)

    u0 = gpu_used_bytes()
    vol = load_nvdb(str(path), filter_type="nearest")
    dr.sync_thread()
    u1 = gpu_used_bytes()
    held = u1 - u0
    # Dr.Jit's accounting: the mapped grid is the volume's one large variable
    from nanovdb_mitsuba import volume_facts
    backend_bytes = volume_facts(vol)["backend_bytes"]
    print(f"grid {size:,} B; NVML +{held:,} B ({held / size:.4f} x); "
          f"backend_bytes {backend_bytes:,} B ({backend_bytes / size:.6f} x)")
    assert size <= backend_bytes <= size + 64
    assert 0.99 * size <= held <= 1.01 * size
    # It is the grid: a voxel of the first leaf (value_at of big_grid.cpp)
    v = eval_points(vol, np.array([[0.5 / 128, 0.5 / 2304, 0.5 / 4096]], np.float32))
    assert 0.5 <= v[0] < 1.5

    del vol
    settle_gpu()
    u2 = gpu_used_bytes()
    print(f"after release: {u2 - u0:+,} B")
    assert u2 - u0 <= 4 * 2**20, "the grid's device memory was not released"


@pytest.mark.parametrize("name", ["fog_sphere", "noisy_cloud", "random_cube", "lower_tiles",
                                  "root_tiles_negative", "nonzero_background"])
def test02_cuda_lookups_match_llvm(make_grid, name):
    # Same points, same grid, same code path: nearest is bit-identical,
    # trilinear equal up to fused multiply-add contraction (1e-6).
    if not has_llvm():
        pytest.skip("Dr.Jit's LLVM backend is not available")
    _setup_variant("cuda_ad_rgb")
    nvdb, _ = make_grid(name, dense=False)
    rng = np.random.default_rng(3)
    pts = rng.uniform(-0.05, 1.05, size=(200_000, 3)).astype(np.float32)
    out = {}
    for variant in ["llvm_ad_rgb", "cuda_ad_rgb"]:
        _setup_variant(variant)
        for filt in ["nearest", "trilinear"]:
            out[variant, filt] = eval_points(load_nvdb(nvdb, filter_type=filt), pts)
    assert np.array_equal(out["llvm_ad_rgb", "nearest"], out["cuda_ad_rgb", "nearest"])
    np.testing.assert_allclose(out["llvm_ad_rgb", "trilinear"], out["cuda_ad_rgb", "trilinear"],
                               rtol=1e-6, atol=1e-7)
