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
- "ball": sphere_tiny.obj, an analytic sphere here.
- torus1 / torus2: tori of the same centre, axis and radii as the originals
  (torus1: R 0.567, r 0.142; torus2: R 1.087, r 0.272).
- "panel": angled_cube.obj, a thin box (2.39 x 0.72 x 0.16) given by its
  centre and edges.
- camera: perspective from (0, 0.5, 4) towards (0, -0.5, 0), near clip 1,
  box filter, 48^2 by default; max_depth 6 (16 for the two scenes without
  the backdrop), as the scenes' includes set them.

SCENES lists the 12 scenes of Mitsuba 3.9.1's folder; scene() builds one.
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
    img[6:9, 20:24] = [8.0, 6.8, 5.2]
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


def torus_obj(directory, name, center, axis, major, minor):
    """A torus about `axis` (unit vector) through `center`."""
    path = Path(directory) / f"{name}.obj"
    if not path.exists():
        axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
        # an orthonormal frame (u, v, axis)
        u = np.cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0])
        u /= np.linalg.norm(u)
        v = np.cross(axis, u)
        segments, sides = 48, 24
        vertices, faces = [], []
        for i in range(segments):
            a = 2 * math.pi * i / segments
            for j in range(sides):
                b = 2 * math.pi * j / sides
                r = major + minor * math.cos(b)
                p = (np.asarray(center) + r * (math.cos(a) * u + math.sin(a) * v)
                     + minor * math.sin(b) * axis)
                vertices.append(tuple(p))
        for i in range(segments):
            for j in range(sides):
                a0, b0 = i * sides + j, ((i + 1) % segments) * sides + j
                a1 = i * sides + (j + 1) % sides
                b1 = ((i + 1) % segments) * sides + (j + 1) % sides
                faces += [(a0, b0, b1), (a0, b1, a1)]
        write_obj(path, vertices, faces)
    return str(path)


def panel_obj(directory, offset=(0.0, 0.0, 0.0)):
    """angled_cube.obj: a thin box from a corner and its three edges."""
    path = Path(directory) / f"panel_{offset[0]:g}.obj"
    if not path.exists():
        corner = np.array([1.885, -0.939, 0.487]) + np.asarray(offset)
        edges = [np.array([-1.059, 1.995, -0.801]), np.array([-0.127, -0.454, -0.551]),
                 np.array([0.138, 0.032, -0.060])]
        vertices = [tuple(corner + i * edges[0] + j * edges[1] + k * edges[2])
                    for i in (0, 1) for j in (0, 1) for k in (0, 1)]
        idx = lambda i, j, k: 4 * i + 2 * j + k
        faces = []
        for axis in range(3):
            for side in (0, 1):
                quad = []
                for a, b in ((0, 0), (1, 0), (1, 1), (0, 1)):
                    ijk = [0, 0, 0]
                    ijk[axis] = side
                    ijk[(axis + 1) % 3], ijk[(axis + 2) % 3] = a, b
                    quad.append(idx(*ijk))
                faces += [(quad[0], quad[1], quad[2]), (quad[0], quad[2], quad[3])]
        write_obj(path, vertices, faces)
    return str(path)


BALL = {"type": "sphere", "center": [0.0, -0.1043, 0.0], "radius": 0.757}

SCENES = ["hetero_sigmat", "hetero_sigmat_albedo", "hetero_spectral_sigmat",
          "hetero_spectral_sigmat_no_scattering", "homo_area_light", "homo_dielectric_envmap",
          "homo_emitter_inside_medium", "homo_null_envmap", "homo_obj_inside_medium",
          "homo_roughdielectric_spot", "homo_spectral_sigmat", "surf_area_light"]

# The integrator each scene's file names (volpath unless it says volpathmis)
SCENE_INTEGRATOR = {name: "volpathmis" if name in ("hetero_spectral_sigmat",
                                                   "homo_spectral_sigmat") else "volpath"
                    for name in SCENES}


def homogeneous(scale, sigma_t, albedo):
    return {"type": "homogeneous", "scale": scale,
            "sigma_t": {"type": "rgb", "value": list(sigma_t)},
            "albedo": {"type": "rgb", "value": list(albedo)},
            "phase": {"type": "isotropic"}}


def water(kind="thindielectric"):
    return {"type": kind, "int_ior": "water", "ext_ior": "air"}


def scene(name, directory, integrator, plugin="gridvolume", res=48, spp=64, volume_args=None):
    """Scene `name` of SCENES. `integrator`: a plugin name (max_depth as the
    scene's) or a dict; `plugin`: the grid volume plugin of the
    heterogeneous scenes (nanovdbvolume gets gridvolume's data and, by
    default, its edge convention)."""
    no_bg = name in ("homo_dielectric_envmap", "homo_roughdielectric_spot")
    if isinstance(integrator, str):
        integrator = {"type": integrator, "max_depth": 16 if no_bg else 6}
    if name.startswith("hetero") and name != "hetero_spectral_sigmat_no_scattering":
        return hetero_scene(name, directory, integrator, plugin, res, spp,
                            volume_args=volume_args)
    d = {"type": "scene", "integrator": integrator, "sensor": camera(res, spp)}
    if not no_bg:
        d.update(backdrop())
    sky = {"type": "envmap", "bitmap": sky_bitmap()}
    pedestal = {"type": "obj", "filename": pedestal_obj(directory)}
    ball = dict(BALL)
    if name == "hetero_spectral_sigmat_no_scattering":
        med = {"type": "heterogeneous", "scale": 5.0, "albedo": {"type": "rgb", "value": [0, 0, 0]},
               "sigma_t": {"type": "constvolume", "value": {"type": "rgb", "value": [0.5, 0.4, 0.3]},
                           "to_world": mi.ScalarTransform4f().translate([-0.5, -0.5, -0.5])},
               "phase": {"type": "isotropic"}}
        d.update(sky=sky, cube=medium_cube(med),
                 pedestal={**pedestal, "bsdf": {"type": "diffuse"}})
    elif name == "homo_area_light":
        med = homogeneous(2.5, (1, 1, 1), (0.99, 0.999, 0.99))
        d.update(ball={**ball, "bsdf": {"type": "null"}, "interior": med},
                 pedestal={**pedestal, "bsdf": water(), "interior": med},
                 panel={"type": "obj", "filename": panel_obj(directory, (0.8, 0, 0)),
                        "bsdf": {"type": "diffuse", "reflectance": 0.0},
                        "emitter": {"type": "area", "radiance": {
                            "type": "rgb", "value": [18.387, 10.9873, 8.75357]}}})
    elif name == "homo_dielectric_envmap":
        med = homogeneous(0.5, (1, 1, 1), (0.99, 0.7, 0.99))
        d.update(sky=sky, ball={**ball, "bsdf": water("dielectric"), "interior": med},
                 pedestal={**pedestal, "bsdf": water("dielectric"), "interior": med})
    elif name == "homo_emitter_inside_medium":
        med = homogeneous(5.0, (1, 1, 1), (0.99, 0.99, 0.999))
        d.update(sky={**sky, "scale": 0.4},
                 ball={**ball, "bsdf": water(), "interior": med},
                 pedestal={**pedestal, "bsdf": water(), "interior": med},
                 torus1={"type": "obj", "bsdf": {"type": "diffuse", "reflectance": 0.0},
                         "filename": torus_obj(directory, "torus1", (-0.07, 0.1305, -0.0892),
                                               (-0.141, 0.618, 0.773), 0.567, 0.142),
                         "emitter": {"type": "area", "radiance": {
                             "type": "spectrum",
                             "value": [(400, 0.0), (500, 0.3), (600, 0.8), (700, 1.1)]}}},
                 torus2={"type": "obj", "filename": torus_obj(
                     directory, "torus2", (-0.4803, 0.8545, -0.5486), (0.872, 0.487, 0.054),
                     1.087, 0.272), "bsdf": {"type": "roughplastic", "diffuse_reflectance": {
                         "type": "rgb", "value": [0.05, 0.2, 0.05]}}})
    elif name == "homo_null_envmap":
        med = homogeneous(3.0, (1, 1, 1), (0.99, 0.5, 0.5))
        d.update(sky=sky, ball={**ball, "bsdf": {"type": "null"}, "interior": med},
                 pedestal={**pedestal, "bsdf": {"type": "null"}, "interior": med})
    elif name == "homo_obj_inside_medium":
        med = homogeneous(2.0, (1, 1, 1), (0.99, 0.7, 0.7))
        d.update(sky=sky, ball={**ball, "bsdf": water(), "interior": med},
                 pedestal={**pedestal, "bsdf": water(), "interior": med},
                 torus1={"type": "obj", "filename": torus_obj(
                     directory, "torus1", (-0.07, 0.1305, -0.0892), (-0.141, 0.618, 0.773),
                     0.567, 0.142), "bsdf": {"type": "roughplastic", "diffuse_reflectance": {
                         "type": "rgb", "value": [0.9, 0.99, 0.97]}}},
                 torus2={"type": "obj", "filename": torus_obj(
                     directory, "torus2", (-0.4803, 0.8545, -0.5486), (0.872, 0.487, 0.054),
                     1.087, 0.272), "bsdf": {"type": "diffuse", "reflectance": 1.0}})
    elif name == "homo_roughdielectric_spot":
        med = {"type": "homogeneous", "scale": 1.0,
               "albedo": {"type": "rgb", "value": [0.101, 0.105, 0.109]},
               "sigma_t": {"type": "rgb", "value": [0.102, 0.993, 0.103]},
               "phase": {"type": "isotropic"}}
        rough = {"type": "roughdielectric", "alpha": 0.3, "int_ior": 1.3, "ext_ior": "air"}
        d.update(spot={"type": "spot", "intensity": {"type": "rgb", "value": [1.0, 1.0, 1.0]},
                       "cutoff_angle": 60.0,
                       "to_world": mi.ScalarTransform4f().look_at(
                           origin=[0, -0.5, -2.0], target=[0, 0.5, 0], up=[0, 1, 0])},
                 ball={**ball, "bsdf": rough, "interior": med},
                 pedestal={**pedestal, "bsdf": rough, "interior": med})
    elif name == "homo_spectral_sigmat":
        med = homogeneous(10.0, (1, 0.2, 1), (0.5, 0.5, 0.99))
        d.update(sky=sky, ball={**ball, "bsdf": {"type": "null"}, "interior": med},
                 pedestal={**pedestal, "bsdf": {"type": "null"}, "interior": med})
    elif name == "surf_area_light":
        d.update(sky=sky,
                 ball={**ball, "bsdf": {"type": "plastic", "diffuse_reflectance": {
                     "type": "rgb", "value": [0.5, 0.3, 0.2]}}},
                 pedestal={**pedestal, "bsdf": {"type": "roughplastic", "diffuse_reflectance": {
                     "type": "rgb", "value": [0.2, 0.7, 0.7]}}},
                 panel={"type": "obj", "filename": panel_obj(directory, (0.8, 0, 0)),
                        "bsdf": {"type": "diffuse", "reflectance": 0.0},
                        "emitter": {"type": "area", "radiance": {
                            "type": "rgb", "value": [18.387, 10.9873, 8.75357]}}})
    else:
        raise ValueError(name)
    return d
