"""Mitsuba 3.9.1 alone (no nanovdb_mitsuba): prbvolpath + gridvolume, a step
(render + backward) frozen with dr.freeze, against the same step unfrozen on
a twin scene, after params.update() of the values by the factors below.
Replays after updates give infinite and NaN images and gradients.
Output (Dr.Jit 1.5.0, llvm_ad_rgb): upstream_prbvolpath_freeze.txt"""
import numpy as np, drjit as dr, mitsuba as mi
mi.set_variant("llvm_ad_rgb")
rng = np.random.default_rng(1)
x = np.linspace(-1, 1, 24); z, y, x = np.meshgrid(x, x, x, indexing="ij")
ball = (2.5 * np.clip(1 - 1.4*np.sqrt(x*x+y*y+z*z), 0, None) * rng.uniform(0.5, 1.5, x.shape)).astype(np.float32)
def scene():
    return mi.load_dict({"type": "scene", "integrator": {"type": "prbvolpath", "max_depth": 6},
        "sensor": {"type": "perspective", "fov": 40,
                   "to_world": mi.ScalarTransform4f().look_at([0.7, 0.6, 2.1], [0.5, 0.5, 0.5], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 16, "height": 16, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": 4}},
        "emitter": {"type": "constant"},
        "cube": {"type": "cube", "bsdf": {"type": "null"},
                 "to_world": mi.ScalarTransform4f().translate(0.5).scale(0.5),
                 "interior": {"type": "heterogeneous", "scale": 3.0, "albedo": 0.7,
                              "sigma_t": {"type": "gridvolume", "data": mi.TensorXf(ball[..., None])}}}})
scenes = [scene(), scene()]
key = "cube.interior_medium.sigma_t.data"
def step(scene, seed):
    params = mi.traverse(scene); params.keep(key)
    image = mi.render(scene, params, seed=seed)
    dr.backward(dr.mean(image))
    return image
frozen = dr.freeze(step)
out = {}
facs = (0.5, 0.7, 1.0, 1.3, 2.0, 1.1, 0.9, 1.5)
for scene, f in zip(scenes, (frozen, step)):
    params = mi.traverse(scene)
    for i, fac in enumerate(facs):
        params[key] = mi.TensorXf((ball * fac)[..., None]); params.update()
        dr.enable_grad(params[key]); params.update()
        image = f(scene, dr.opaque(mi.UInt32, 7 * i))
        out.setdefault(i, []).append((np.array(image), np.array(dr.grad(params[key]))))
        dr.disable_grad(params[key])
for i in range(len(facs)):
    (a, ga), (b, gb) = out[i]
    print(i, facs[i], "img maxdiff %.3g" % np.abs(a-b).max(), "grad maxdiff %.3g of %.3g" % (np.abs(ga-gb).max(), np.abs(gb).max()))
print("recordings", frozen.n_recordings, "mitsuba", mi.__version__, "drjit", dr.__version__)
