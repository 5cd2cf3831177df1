"""A NanoVDB volume in a scene of its own: placed in its world space
(use_grid_transform), inside a null-BSDF box fitted to it, framed by a
camera, lit by a sky and a sun."""
import math


# Points of the density lattice (below) on the JIT backends, and on the
# scalar ones, where each lookup is a call from Python
LATTICE_POINTS = 1 << 21
LATTICE_POINTS_SCALAR = 1 << 17


def density_lattice(volume, points=None):
    """The volume's density over its world box (volume.bbox()): eval() (the
    mean of its channels) at the midpoints of a lattice of cells. The
    lattice has 2 cells per voxel of the index box along each axis where
    that makes at most `points` cells (then the samples' mean is exactly
    the mean of the trilinear density over the box: each half-voxel cell
    lies within one trilinear piece, where the midpoint rule is exact),
    else about `points` cells in the same proportions. points None:
    LATTICE_POINTS on the JIT backends, LATTICE_POINTS_SCALAR on the scalar
    ones. Returns (values: numpy (n,), the lattice's cells per axis)"""
    import numpy as np
    import drjit as dr
    import mitsuba as mi
    from .facts import volume_facts
    jit = dr.is_jit_v(mi.Float)
    if points is None:
        points = LATTICE_POINTS if jit else LATTICE_POINTS_SCALAR
    bb = volume.bbox()
    n = [2 * max(int(d), 1) for d in volume_facts(volume)["index_dims"]]
    total = float(n[0]) * n[1] * n[2]
    if total > points:
        f = (points / total) ** (1.0 / 3.0)
        n = [max(1, int(x * f)) for x in n]
    axes = [float(bb.min[k]) + (np.arange(n[k]) + 0.5) / n[k] * float(bb.max[k] - bb.min[k])
            for k in range(3)]
    pos = [a.ravel() for a in np.meshgrid(*axes, indexing="ij")]
    if jit:
        it = dr.zeros(mi.Interaction3f, len(pos[0]))
        it.p = mi.Point3f(*(a.astype(np.float32) for a in pos))
        v = volume.eval(it)
        values = np.array(sum(v[c] for c in range(len(v))) / len(v), dtype=np.float64)
    else:
        it = dr.zeros(mi.Interaction3f)
        values = np.empty(len(pos[0]))
        for i in range(len(values)):
            it.p = mi.Point3f(pos[0][i], pos[1][i], pos[2][i])
            v = volume.eval(it)
            values[i] = sum(float(v[c]) for c in range(len(v))) / len(v)
    return values, n


def default_scale(volume, optical_depth=8.0):
    """A density scale from the plugin's per-node bounds of the density:
    optical_depth / (B x the box's mean extent), B the mean over the box of
    those bounds (local_majorant_ratio x max()). A medium as dense as its
    bounds everywhere would have a mean optical depth of `optical_depth`
    across its box; the density itself lies below its bounds, most of all
    where it is sparse or noisy, so its real mean optical depth is lower
    (mean_optical_depth() gives it; bench/results/render_defaults.md has it
    for the shared files: from 0.01 to 6.2). The bounds follow where the
    density is, so a fire stays visible through its smoke, which a real
    mean of `optical_depth` over the whole box buries (the report's last
    table). 1 for a volume without density (max() 0)."""
    from .facts import volume_facts
    vmax = volume.max()
    ratio = volume_facts(volume)["local_majorant_ratio"]
    bb = volume.bbox()
    extent = sum(float(bb.max[k] - bb.min[k]) for k in range(3)) / 3.0
    mean = max(vmax * ratio, 1e-12)
    if not (vmax > 0.0) or not (extent > 0.0):
        return 1.0
    return optical_depth / (mean * extent)


def mean_optical_depth(volume, scale):
    """The mean optical depth across the volume's world box (volume.bbox(),
    the box framed_scene fits the medium to) at density scale `scale`: the
    optical depth along a line through the box parallel to axis a, averaged
    over those lines, is scale x rho x L_a (rho: the density's mean over the
    box, L_a: the box's extent); this is its mean over the three axes, scale
    x rho x (L_x + L_y + L_z) / 3. rho: the mean of density_lattice(), exact
    for an index box of up to LATTICE_POINTS / 8 voxels (LLVM, CUDA;
    LATTICE_POINTS_SCALAR / 8 on the scalar variants), a midpoint estimate
    beyond; for 3 channels (a colour extinction), their mean. 0 for a volume
    without density (max() 0)."""
    if not (volume.max() > 0.0):
        return 0.0
    bb = volume.bbox()
    extent = sum(float(bb.max[k] - bb.min[k]) for k in range(3)) / 3.0
    return scale * float(density_lattice(volume)[0].mean()) * extent


def _project(p, origin, target, fov):
    """Image coordinates in [-1, 1]^2 (x right, y up) of world point p seen
    from origin towards target with up +y and a square film; None if behind"""
    def sub(a, b): return [a[k] - b[k] for k in range(3)]
    def dot(a, b): return sum(a[k] * b[k] for k in range(3))
    def cross(a, b): return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                             a[0] * b[1] - a[1] * b[0]]
    def norm(a):
        n = math.sqrt(dot(a, a))
        return [x / n for x in a]
    w = norm(sub(target, origin))
    u = norm(cross(w, [0.0, 1.0, 0.0]))
    v = cross(u, w)
    d = sub(p, origin)
    z = dot(d, w)
    if z <= 0:
        return None
    t = math.tan(math.radians(fov) / 2)
    return dot(d, u) / (z * t), dot(d, v) / (z * t)


def camera(bbox, fov=35.0, direction=(1.0, 0.55, 1.3), fill=0.85):
    """A camera that frames the box: looking at its centre from `direction`,
    at the smallest distance where all 8 corners lie within `fill` of the
    frame's half-width and half-height. The box spans that share of the
    frame where it is widest; the volume inside spans less, as much less
    as it leaves its box empty seen from `direction` (on the shared files
    34-69 % of the width and 1-25 % of the pixels:
    bench/results/render_defaults.md)"""
    c = [0.5 * (bbox.min[k] + bbox.max[k]) for k in range(3)]
    r = 0.5 * math.sqrt(sum((bbox.max[k] - bbox.min[k]) ** 2 for k in range(3)))
    r = max(r, 1e-6)
    n = math.sqrt(sum(d * d for d in direction))
    dirn = [d / n for d in direction]
    corners = [[bbox.max[k] if (i >> k) & 1 else bbox.min[k] for k in range(3)] for i in range(8)]

    def fits(dist):
        origin = [c[k] + dirn[k] * dist for k in range(3)]
        for p in corners:
            q = _project(p, origin, c, fov)
            if q is None or abs(q[0]) > fill or abs(q[1]) > fill:
                return False
        return True

    hi = r / math.sin(math.radians(fov) / 2) * 1.2  # the bounding sphere fits
    while not fits(hi):
        hi *= 1.5
    lo = r * 1.01  # outside the sphere
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if fits(mid):
            hi = mid
        else:
            lo = mid
    origin = [c[k] + dirn[k] * hi for k in range(3)]
    return dict(origin=origin, target=c, fov=fov, distance=hi, radius=r)


def enclosing_cube(mi, volume, margin=1e-4, box=None):
    """to_world of a "cube" shape ([-1, 1]^3) that encloses the volume's
    world box (volume.bbox(): with use_grid_transform, the grid's world box)
    with a relative margin, so that the medium inside it is not clipped.
    box: another box (an object with .min and .max) to enclose instead"""
    bb = box if box is not None else volume.bbox()
    centre = [0.5 * (bb.min[k] + bb.max[k]) for k in range(3)]
    half = [max(0.5 * (bb.max[k] - bb.min[k]), 1e-6) * (1.0 + margin) for k in range(3)]
    return mi.ScalarTransform4f().translate(centre).scale(half)


class _Box:
    """A world box as lists (what camera() reads of a BoundingBox3f)"""
    def __init__(self, lo, hi):
        self.min, self.max = [float(x) for x in lo], [float(x) for x in hi]


def framed_scene(mi, filename, grid="", scale=None, res=256, spp=64,
                 integrator="volpathlocal", albedo=None, filter_type="trilinear",
                 invalid_values="error", sequence=None, emission_grid=None, volume=None):
    """(scene dict, info) for `filename` (.nvdb). `scale` None: default_scale().
    albedo None: 0.9, or the sequence's. info holds the volume's world bbox,
    the camera and the scale used.
    sequence: a sequence summary (the plan of sequence.py: "bbox_min",
    "bbox_max", the union of every frame's world box, "scale", "grid",
    "albedo" and "emission"): the camera frames that union, `scale` None
    takes its scale and `grid` "" its grid, so that every frame of an
    animation gets the same camera and scale. With a sequence,
    filename None gives the scene of an empty frame (camera and lights, no box).
    A sequence's "emission" (fire: its grid, mode and fixed scales) makes
    the medium glow with that grid of `filename` (emission_grid: another
    name for it in this frame, or "none"); info["emission"] says what glows,
    None where nothing does, info["emission_why_not"] why not. volume:
    `filename`'s volume, if the caller has loaded it already (a sequence's
    frame: the same dict as here)."""
    if sequence is not None and not grid:
        grid = sequence.get("grid", "")
    if albedo is None:
        albedo = float(sequence.get("albedo", 0.9)) if sequence is not None else 0.9
    if volume is None and (filename is not None or sequence is None):
        vdict = {"type": "nanovdbvolume", "filename": str(filename), "use_grid_transform": True,
                 "filter_type": filter_type, "invalid_values": invalid_values}
        if grid:
            vdict["grid"] = grid
        volume = mi.load_dict(vdict)
    union = _Box(sequence["bbox_min"], sequence["bbox_max"]) if sequence is not None else None
    if sequence is not None:
        bb = union if volume is None else volume.bbox()
        if scale is None:
            scale = float(sequence["scale"])
        cam = camera(union)
    else:
        bb = volume.bbox()
        if scale is None:
            scale = default_scale(volume)
        cam = camera(bb)
    T = mi.ScalarTransform4f
    scene = {
        "type": "scene",
        "integrator": {"type": integrator, "max_depth": 64},
        "sensor": {
            "type": "perspective",
            "fov": cam["fov"],
            "to_world": T().look_at(origin=cam["origin"], target=cam["target"], up=[0, 1, 0]),
            "sampler": {"type": "independent", "sample_count": spp},
            "film": {"type": "hdrfilm", "width": res, "height": res,
                     "rfilter": {"type": "gaussian"}},
        },
        # Next-event estimation goes to the sun alone (the sky's
        # sampling_weight 0): phase sampling, isotropic, draws directions in
        # proportion to a constant sky's light (up to visibility), and MIS
        # then gives the sky it finds its full weight, while the sun, a delta
        # light, can only be reached by a shadow ray. With Mitsuba's default,
        # half the shadow rays went to the sky: 1.8-1.9x the variance per sample
        # on the shared smoke and the generator's cloud, same mean (bench/
        # INTEGRATOR_LOG.md, 2026-11-27, issue 34)
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.15, 0.18, 0.25]},
                "sampling_weight": 0.0},
        "sun": {"type": "directional", "direction": [-1, -1, -0.5],
                "irradiance": {"type": "rgb", "value": [6, 5.7, 5.1]}},
    }
    if volume is not None:
        # A sequence's frames: the cube fits the union box, the same in every
        # frame (the medium ends at its volume's own box inside it), so that
        # the scene's bounds, which the sun's sampling takes as constants of
        # the kernel, do not make each frame compile its own kernel
        scene["box"] = {
            "type": "cube",  # [-1, 1]^3, fitted to the volume's world box
            "to_world": enclosing_cube(mi, volume, box=union),
            "bsdf": {"type": "null"},
            "interior": {"type": "heterogeneous", "sigma_t": volume,
                         "albedo": {"type": "rgb", "value": [albedo] * 3}, "scale": scale},
        }
    info = dict(bbox_min=[float(x) for x in bb.min], bbox_max=[float(x) for x in bb.max],
                camera=cam, scale=scale, volume=volume, emission=None)
    mapping = sequence.get("emission") if sequence is not None else None
    if volume is not None and mapping and emission_grid != "none":
        # The fire of a sequence's frame: the plan's grid, mode and scales
        # (one mapping for every frame), not this frame's own max()
        from . import fire
        name = emission_grid or mapping["grid"]
        try:
            rendered, _, why_not = fire.add_emission(mi, scene, filename, name, mapping["mode"],
                                                     filter_type, **fire.fixed_scales(mapping))
        except RuntimeError as e:  # e.g. no such grid in this frame's file
            rendered, why_not = None, str(e).rsplit("[NanoVDBVolume] ", 1)[-1].strip()
        info["emission"] = rendered
        if why_not:
            info["emission_why_not"] = why_not
    return scene, info
