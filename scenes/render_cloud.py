"""Renders a .nvdb volume with nanovdbvolume (the same scene as cloud.xml).

    python3 scenes/render_cloud.py VOLUME.nvdb OUT.png [--variant llvm_ad_rgb]
                                   [--grid NAME] [--filter trilinear|nearest]
                                   [--integrator volpathlocal|volpath]
                                   [--spp 64] [--res 256]

The integrator is volpathlocal (volpath with majorants per node of the
NanoVDB tree: the same image, faster on sparse volumes); --integrator volpath
renders with Mitsuba's own.
"""
import argparse
import os
import time

import mitsuba as mi

HERE = os.path.dirname(os.path.abspath(__file__))


def cloud_scene(volume, grid="", filter_type="trilinear", spp=64, res=256,
                integrator="volpathlocal"):
    """The Python-dict form of scenes/cloud.xml."""
    sigma_t = {"type": "nanovdbvolume", "filename": volume, "filter_type": filter_type}
    if grid:
        sigma_t["grid"] = grid
    return {
        "type": "scene",
        "integrator": {"type": integrator, "max_depth": 64},
        "sensor": {
            "type": "perspective",
            "fov": 35,
            "to_world": mi.ScalarTransform4f().look_at(
                origin=[2.2, 1.6, 2.6], target=[0.5, 0.5, 0.5], up=[0, 1, 0]),
            "sampler": {"type": "independent", "sample_count": spp},
            "film": {"type": "hdrfilm", "width": res, "height": res,
                     "rfilter": {"type": "gaussian"}},
        },
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.6, 0.7, 0.9]}},
        "sun": {"type": "directional", "direction": [-1, -1, -0.5],
                "irradiance": {"type": "rgb", "value": [4, 3.8, 3.4]}},
        "cube": {
            "type": "cube",
            "to_world": mi.ScalarTransform4f().translate([0.5, 0.5, 0.5]).scale(0.5),
            "bsdf": {"type": "null"},
            "interior": {
                "type": "heterogeneous",
                "sigma_t": sigma_t,
                "albedo": {"type": "rgb", "value": [0.9, 0.9, 0.9]},
                "scale": 40.0,
            },
        },
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("volume")
    ap.add_argument("output")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--grid", default="")
    ap.add_argument("--filter", default="trilinear", choices=["trilinear", "nearest"])
    ap.add_argument("--integrator", default="volpathlocal", choices=["volpathlocal", "volpath"])
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--build", default=None,
                    help="a build directory holding plugins/nanovdbvolume.so and volpathlocal.so "
                         "(default: where `import nanovdb_mitsuba` finds them)")
    args = ap.parse_args()

    import nanovdb_mitsuba  # noqa: F401  (Mitsuba now finds the plugins)
    mi.set_variant(args.variant)
    if args.build:
        mi.file_resolver().prepend(os.path.abspath(args.build))
    scene = mi.load_dict(cloud_scene(os.path.abspath(args.volume), args.grid,
                                     args.filter, args.spp, args.res, args.integrator))
    t0 = time.time()
    image = mi.render(scene)
    mi.util.write_bitmap(args.output, image)
    print(f"{args.output}: {args.res}x{args.res}, {args.spp} spp, {args.variant}, "
          f"{args.integrator}, {time.time() - t0:.2f} s")


if __name__ == "__main__":
    main()
