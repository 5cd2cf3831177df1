"""
Mitsuba 3.9.1's participating-media test scenes (mitsuba-data,
tests/scenes/participating_media), rebuilt here so that the tests need no
download: the grids from the formulas that made them, the meshes as
equivalents of the same size and place, the environment map as a small
procedural sky.

- sigmat (16^3): a 5 in the block x > 0.2, y > 0.7, z < 0.5 (unit
  coordinates of the voxel's corner), elsewhere (sin(16 (x + 4 ((y - 0.5)^2
  - 0.25))) + 1) / 2.
- albedo (16^3, RGB): from the same kind of waves, clipped to [0, 1].
- the medium's box: the cube [-0.75, 0.75]^3, null BSDF; its volumes span
  it (gridvolume's unit cube, scaled by 1.5 and moved by -0.75).
- "pedestal": an equivalent of sphere_base.obj, a surface of revolution
  through the original's rings, from y = -1.015 to -0.524, so that, like
  the original, it cuts through the bottom face of the medium's cube
  (y = -0.75).
- "ball": sphere_tiny.obj, a sphere of radius 0.757 at (0, -0.104, 0).
- the backdrop: a floor at y = -1.045 and a wall at z = -3.122, checkered
  0.2 / 0.4 (background.obj with its checkerboard texture).
- camera: perspective from (0, 0.5, 4) towards (0, -0.5, 0), near clip 1,
  box filter, 48^2 by default.
"""

import math
from pathlib import Path

import numpy as np
import drjit as dr
import mitsuba as mi

RES = 16


def sigmat_values(res=RES):
    """The sigmat grid: a float array of shape (z, y, x)."""
    out = np.zeros((res, res, res), dtype=np.float32)
    for z in range(res):
        for y in range(res):
            for x in range(res):
                out[z, y, x] = _sigmat(x / res, y / res, z / res)
    return out


def _sigmat(x, y, z):
    if x > 0.2 and y > 0.7 and z < 0.5:
        return 5.0
    return max(0.0, (math.sin(16 * (x + 4 * ((y - 0.5) ** 2 - 0.25))) + 1) * 0.5)


def albedo_values(res=RES):
    """The albedo grid: a float array of shape (z, y, x, 3) in [0, 1]."""
    def wave(x, y):
        return math.cos(45 * (x + ((y - 0.7) ** 2 - 0.25)) + 1) * 0.5
    out = np.zeros((res, res, res, 3), dtype=np.float32)
    for z in range(res):
        for y in range(res):
            for x in range(res):
                u, v, w = x / res, y / res, z / res
                out[z, y, x, 0] = wave(u, v) + 0.5 * math.cos(v) + 0.5
                out[z, y, x, 1] = _sigmat((u + 0.3) % 1, (v + 0.7) % 1, w)
                out[z, y, x, 2] = wave(u, v)
    return np.clip(out, 0, 1)


def write_obj(path, vertices, faces):
    """A Wavefront OBJ of triangles (faces: 0-based index triples)."""
    with open(path, "w") as f:
        for v in vertices:
            f.write("v %.6f %.6f %.6f\n" % tuple(v))
        for t in faces:
            f.write("f %d %d %d\n" % (t[0] + 1, t[1] + 1, t[2] + 1))
    return str(path)


def lathe(profile, segments=64):
    """A closed surface of revolution about the y axis from a profile of
    (radius, y) points, first and last on the axis (radius 0)."""
    vertices, faces = [], []
    ring = []
    for r, y in profile:
        if r == 0:
            ring.append([len(vertices)])
            vertices.append((0.0, y, 0.0))
        else:
            ring.append(list(range(len(vertices), len(vertices) + segments)))
            for s in range(segments):
                a = 2 * math.pi * s / segments
                vertices.append((r * math.cos(a), y, r * math.sin(a)))
    for lo, hi in zip(ring[:-1], ring[1:]):
        for s in range(segments):
            s1 = (s + 1) % segments
            if len(lo) == 1:
                faces.append((lo[0], hi[s1], hi[s]))
            elif len(hi) == 1:
                faces.append((lo[s], lo[s1], hi[0]))
            else:
                faces.append((lo[s], lo[s1], hi[s1]))
                faces.append((lo[s], hi[s1], hi[s]))
    return vertices, faces


# sphere_base.obj's rings (radius, height), read off the original: a foot,
# a waist and a cone opening upwards that crosses the cube's bottom face
# (y = -0.75) at about 52 degrees from the horizontal, up to a rim
PEDESTAL_PROFILE = [(0.0, -1.0146), (0.9046, -1.0146), (0.8983, -0.9692), (0.5765, -0.9633),
                    (0.3495, -0.9239), (0.7352, -0.8505), (0.7229, -0.8425), (0.5328, -0.8337),
                    (0.3495, -0.7994), (0.767, -0.5241), (0.0, -0.5241)]


def pedestal_obj(directory):
    path = Path(directory) / "pedestal.obj"
    if not path.exists():
        write_obj(path, *lathe(PEDESTAL_PROFILE))
    return str(path)


def torus(center, axis_angle, major, minor, segments=48, sides=24):
    """Vertices and faces of a torus (about y, then rotated about x)."""
    c, s = math.cos(math.radians(axis_angle)), math.sin(math.radians(axis_angle))
    vertices, faces = [], []
    for i in range(segments):
        a = 2 * math.pi * i / segments
        for j in range(sides):
            b = 2 * math.pi * j / sides
            r = major + minor * math.cos(b)
            x, y, z = r * math.cos(a), minor * math.sin(b), r * math.sin(a)
            y, z = c * y - s * z, s * y + c * z
            vertices.append((x + center[0], y + center[1], z + center[2]))
    for i in range(segments):
        for j in range(sides):
            a, b = i * sides + j, ((i + 1) % segments) * sides + j
            a1, b1 = i * sides + (j + 1) % sides, ((i + 1) % segments) * sides + (j + 1) % sides
            faces.append((a, b, b1))
            faces.append((a, b1, a1))
    return vertices, faces


def sky_bitmap():
    """A small procedural environment in place of museum.exr: a blue sky
    brightening to the horizon, a darker ground and a warm sun."""
    h, w = 32, 64
    img = np.zeros((h, w, 3), dtype=np.float32)
    for i in range(h):
        theta = (i + 0.5) / h * math.pi
        up = math.cos(theta)
        if up > 0:
            img[i] = np.array([0.4, 0.55, 0.9]) * (0.6 + 0.4 * up) + 0.3 * (1 - up)
        else:
            img[i] = np.array([0.25, 0.22, 0.2]) * (1 + up * 0.5)
    img[6:9, 20:24] = [40.0, 34.0, 26.0]
    return mi.Bitmap(img)


def backdrop():
    """background.obj: floor and back wall, checkered 0.2 / 0.4."""
    T = mi.ScalarTransform4f
    check = {"type": "diffuse", "reflectance": {
        "type": "checkerboard", "color0": 0.2, "color1": 0.4,
        "to_uv": T().scale([16, 16, 1])}}
    return {
        "floor": {"type": "rectangle", "bsdf": check,
                  "to_world": T().translate([0, -1.04493, 0]).rotate([1, 0, 0], -90)
                  .scale([4.684556, 3.12214, 1])},
        "wall": {"type": "rectangle", "bsdf": check,
                 "to_world": T().translate([0, 1.7005, -3.12214]).scale([4.684556, 2.7455, 1])},
    }


def camera(res=48, spp=64):
    return {
        "type": "perspective", "near_clip": 1.0, "far_clip": 1000.0,
        "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0.5, 4], target=[0, -0.5, 0],
                                                    up=[0, 1, 0]),
        "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"},
                 "pixel_format": "luminance" if mi.is_monochromatic else "rgb"},
        "sampler": {"type": "independent", "sample_count": spp},
    }


def grid_volume(values, plugin, **extra):
    """A volume spanning the medium's cube [-0.75, 0.75]^3 from dense
    `values` (z, y, x[, c]): gridvolume or nanovdbvolume (clamped to its
    edge voxels, as gridvolume) on the same tensor."""
    return {"type": plugin, "data": mi.TensorXf(values),
            "to_world": mi.ScalarTransform4f().scale(1.5).translate([-0.5, -0.5, -0.5]),
            **extra}


def medium_cube(medium):
    return {"type": "cube", "bsdf": {"type": "null"}, "interior": medium,
            "to_world": mi.ScalarTransform4f().scale(0.75)}


def hetero_scene(name, directory, integrator, plugin="gridvolume", res=48, spp=64,
                 sigmat=None, volume_args=None, environment=True):
    """The heterogeneous scenes: "hetero_sigmat", "hetero_sigmat_albedo" and
    "hetero_spectral_sigmat" (the albedo grid as a 3-channel extinction).
    `integrator`: a dict or a plugin name; `sigmat`: other values for the
    sigmat grid (e.g. padded)."""
    volume_args = volume_args or {}
    sig = sigmat if sigmat is not None else sigmat_values()
    if name == "hetero_sigmat":
        med = {"type": "heterogeneous", "scale": 5.0,
               "sigma_t": grid_volume(sig, plugin, **volume_args),
               "albedo": {"type": "rgb", "value": [0.99, 0.5, 0.5]},
               "phase": {"type": "isotropic"}}
    elif name == "hetero_sigmat_albedo":
        med = {"type": "heterogeneous", "scale": 5.0,
               "sigma_t": grid_volume(sig, plugin, **volume_args),
               "albedo": grid_volume(albedo_values(), plugin, **volume_args),
               "phase": {"type": "isotropic"}}
    elif name == "hetero_spectral_sigmat":
        med = {"type": "heterogeneous", "scale": 2.0,
               "sigma_t": grid_volume(albedo_values(), plugin, **volume_args),
               "albedo": {"type": "rgb", "value": [0.99, 0.99, 0.99]},
               "phase": {"type": "isotropic"}}
    else:
        raise ValueError(name)
    if isinstance(integrator, str):
        integrator = {"type": integrator, "max_depth": 6}
    scene = {"type": "scene", "integrator": integrator, "sensor": camera(res, spp),
             "cube": medium_cube(med),
             "pedestal": {"type": "obj", "filename": pedestal_obj(directory),
                          "bsdf": {"type": "diffuse"}}}
    scene.update(backdrop())
    if environment:
        scene["sky"] = {"type": "envmap", "bitmap": sky_bitmap()}
    return scene
