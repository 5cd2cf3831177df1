"""The benchmark scene: the volume in a unit cube (null BSDF, heterogeneous
medium, volpath), seen by a turntable of 8 sensors at a fixed elevation.

The lighting and medium are those of scenes/cloud.xml (via
scenes/render_cloud.py): a scattering medium (albedo 0.9, scale 40), a
constant sky and a directional sun, max_depth 64; only the sensors differ.
Both plugins get the same scene: only the `sigma_t` volume's plugin and file
differ. The integrator is `volpath` (Mitsuba's own; scenes/cloud.xml now
defaults to `volpathlocal`) unless the caller asks for `volpathlocal` (the
integrator comparison), with the same parameters.
"""
import math
import os
import sys

import mitsuba as mi

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(ROOT, "scenes"))
from render_cloud import cloud_scene  # noqa: E402

N_SENSORS = 8
# scenes/cloud.xml looks from (2.2, 1.6, 2.6) at the cube's centre: distance
# 2.92, elevation 22 degrees. The turntable keeps both.
RADIUS = 2.92
ELEVATION_DEG = 22.0


def volume_dict(plugin, filename, filter_type, grid="", count_lookups=False):
    """count_lookups (nanovdbvolume only): count lookups and walk steps."""
    d = {"type": plugin, "filename": filename, "filter_type": filter_type}
    if grid and plugin == "nanovdbvolume":
        d["grid"] = grid
    if count_lookups:
        d["count_lookups"] = True
    return d


def sensor_dict(i, res, spp):
    phi = 2 * math.pi * i / N_SENSORS
    el = math.radians(ELEVATION_DEG)
    o = [0.5 + RADIUS * math.cos(el) * math.sin(phi),
         0.5 + RADIUS * math.sin(el),
         0.5 + RADIUS * math.cos(el) * math.cos(phi)]
    return {
        "type": "perspective",
        "fov": 35,
        "to_world": mi.ScalarTransform4f().look_at(origin=o, target=[0.5, 0.5, 0.5],
                                                   up=[0, 1, 0]),
        "sampler": {"type": "independent", "sample_count": spp},
        "film": {"type": "hdrfilm", "width": res, "height": res,
                 "rfilter": {"type": "gaussian"}},
    }


def turntable_scene(volume, res, spp, integrator="volpath"):
    """`volume`: a loaded mi.Volume (or a dict); `integrator`: `volpath` or
    `volpathlocal` (a drop-in replacement: same parameters). Returns the
    scene dict."""
    desc = cloud_scene("unused", spp=spp, res=res, integrator=integrator)
    desc["cube"]["interior"]["sigma_t"] = volume
    del desc["sensor"]
    for i in range(N_SENSORS):
        desc[f"sensor_{i}"] = sensor_dict(i, res, spp)
    return desc
