"""The fireball over its floor, collisions-only against NEE+MIS at about
equal time, beside a reference (issue 35's closing note: the images, looked
at): bench/results/fire_nee_equal_time.png, left to right collisions 32 spp,
mis 16 spp (about the same time: mis costs 2.1-2.4x per sample), mis 1024
spp; one tone map for all three.

    python3 bench/fire_nee_images.py --build BUILD      # ~2 min on 2 cores

A picture, not a measurement: bench/fire_nee.py and bench/nee_bound.py
measure.
"""
import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default=os.path.join(os.path.dirname(HERE), "build"))
    ap.add_argument("--res", type=int, default=160)
    ap.add_argument("--out", default=os.path.join(HERE, "results", "fire_nee_equal_time.png"))
    a = ap.parse_args()
    from child_setup import mitsuba_for
    dr, mi = mitsuba_for("llvm_ad_rgb", os.path.abspath(a.build))
    import emission
    import fire_nee
    case = {"name": "fireball",
            "file": emission.fireball_file(os.path.join(HERE, "data", "emission"),
                                           os.path.abspath(a.build), 128)}
    imgs = {}
    for mode, spp in (("collisions", 32), ("mis", 16), ("mis", 1024)):
        s = mi.load_dict(fire_nee.scene(mi, case, mode, a.res, spp, 1))
        dr.eval(mi.render(s, spp=spp, seed=0))  # (compiles)
        dr.sync_thread()
        t0 = time.perf_counter()
        img = mi.render(s, spp=spp, seed=3)
        dr.eval(img)
        dr.sync_thread()
        imgs[(mode, spp)] = (np.asarray(img, dtype=np.float64)[..., :3],
                             time.perf_counter() - t0)
    ref = imgs[("mis", 1024)][0]

    def tone(x):
        return (np.clip(1 - np.exp(-4.0 * x), 0, 1) ** (1 / 2.2) * 255).astype(np.uint8)

    gap = np.full((a.res, 4, 3), 255, np.uint8)
    row = np.concatenate([tone(imgs[("collisions", 32)][0]), gap, tone(imgs[("mis", 16)][0]),
                          gap, tone(ref)], 1)
    import PIL.Image
    PIL.Image.fromarray(row).save(a.out)
    for k in (("collisions", 32), ("mis", 16)):
        e = np.sqrt(np.mean((imgs[k][0] - ref) ** 2)) / ref.mean()
        print(f"{k[0]} {k[1]} spp: {imgs[k][1]:.2f} s, relative RMSE against mis 1024 spp "
              f"(its own noise included) {e:.3f}")
    print("wrote", a.out)


if __name__ == "__main__":
    main()
