"""Fire in nanovdb-render: which grid of a file glows, in which mode, and
how brightly (the `emissiveheterogeneous` medium's parameters).

Grids are recognised by name, case-insensitively, in this order of
preference when a file holds several (EMISSION_NAMES):

  emission     a radiance grid as such (Blender Mantaflow's "emission");
  flame        the visible fire: Houdini pyro and Blender Mantaflow write
               density, temperature and flame, flame (0..1) where it burns;
  temperature  the wider heat field around it (Houdini: a buoyancy field;
               Blender saves its "heat", about -2..2, under this name): not
               kelvin, and warm well beyond the flames, so after flame;
  heat         the same field under Houdini's classic pyro / Cycles' name.

Houdini's classic "burn" field (fuel burnt in a step) is left out: what its
values mean depends on the solver set-up, so it is never picked by default
(--emission-grid burn --emission-mode radiance renders it).

The defaults, scaled by the loaded grid's max() (an upper bound of what its
lookups return, so the hottest value it can give):

  temperature, heat  temperature mode: kelvin = (value - 0) x
                     temperature_scale, where temperature_scale maps the
                     max to HOTTEST_KELVIN; emission_scale makes the
                     hottest value's blackbody luminance BRIGHTNESS.
  emission, flame    radiance mode: colour FIRE_RGB (a blackbody's colour
                     at 1800 K, luminance 1), emission_scale =
                     BRIGHTNESS / max, so that the strongest value has
                     luminance BRIGHTNESS. A Vec3f "emission" grid keeps its
                     own colour, scaled the same way.

The medium emits sigma_a x Le per unit length, sigma_a = sigma_t (1 -
albedo): the emission shows where the density is, and only with an albedo
below 1 (nanovdb-render: FIRE_ALBEDO).
"""
import math
import os

# In order of preference (see above); matched case-insensitively
EMISSION_NAMES = ("emission", "flame", "temperature", "heat")
# The names read as temperatures; the others as radiance
TEMPERATURE_NAMES = ("temperature", "heat")
MODES = ("radiance", "temperature")

# Kelvin of the hottest value in temperature mode. Blender and Houdini
# temperatures are not kelvin; 2500-3000 K is the hot core of a flame, and
# since a blackbody's luminance falls steeply with T (Y(2400 K) = 0.12
# Y(3000 K), Y(1800 K) = 0.004 Y(3000 K)), only the upper fifth of the
# grid's values glow visibly.
HOTTEST_KELVIN = 3000.0
# The luminance (linear, Y) of the brightest emission Le. nanovdb-render's
# sun gives an irradiance of luminance about 5.7, so a white diffuser facing
# it reflects a radiance of about 1.8. What reaches the camera is Le (1 -
# exp(-sigma_a d)) through the glowing region, less what the smoke around it
# absorbs: on ../shared/data/usd_density_heat_fog.vdb, whose hot core is a
# few voxels, 4 gives a faint core (brightest pixel 0.76), 16 a clipped one
# (1.9), 8 a bright core just at white (see README).
BRIGHTNESS = 8.0
# The same for radiance mode (flame, emission), which scales linearly: a
# flame grid is high (0.3..1) over most of the fire, where a temperature
# grid's blackbody luminance falls steeply below its max, so a lower target
# (on the generated cloud used as flame, 8 turns it all white-yellow: FIRE_RGB's
# red channel is 2.8 x the luminance, and it clips above 1)
FLAME_BRIGHTNESS = 1.0
# The density's albedo in a file with an emission grid (rendered or not,
# --no-emission: the same smoke): sigma_a = 0.4 sigma_t, so that the fire
# glows through its smoke rather than being washed out by the smoke's
# scattering of the sun (0.9, scene.py's default for smoke alone, makes the
# core of usd_density_heat_fog.vdb's fire barely stand out; 0.3 gives a
# sooty black smoke).
FIRE_ALBEDO = 0.6
# What the commands print of how the fire lights its surroundings:
# volpathlocal's default emission_sampling ("mis": next-event estimation
# toward the emission, with MIS against the emission that paths collect)
LIGHTING = "lit by next-event estimation with MIS"
# Radiance mode's colour: a blackbody at 1800 K in linear sRGB, over its
# luminance Y (so Y = 1), the slightly negative blue (-0.019, outside the
# sRGB gamut) clamped to 0. Computed as blackbody_rgb(1800) / Y: the
# integral over 360..830 nm of Planck x mi.cie1931_xyz, then XYZ -> linear
# sRGB (tests/test_render_fire.py recomputes it).
FIRE_RGB = (2.7704, 0.5763, 0.0)
FIRE_KELVIN = 1800.0
# XYZ -> linear sRGB (Mitsuba's xyz_to_srgb)
_XYZ_TO_SRGB = ((3.240479, -1.537150, -0.498535),
                (-0.969256, 1.875991, 0.041556),
                (0.055648, -0.204043, 1.057311))


def blackbody_xyz(mi, kelvin):
    """CIE XYZ of a blackbody at `kelvin`, in Mitsuba's units: the integral
    over [360, 830] nm of Planck's law (W m^-2 sr^-1 nm^-1, as Mitsuba's
    `blackbody` spectrum) x the CIE 1931 curves, times
    MI_CIE_Y_NORMALIZATION: what the emissiveheterogeneous medium's
    temperature mode emits (its Y: 414 at 3000 K, 0.106 at 1500 K). The
    medium's own integral (include/nanovdb_mitsuba/blackbody.h), which its
    plugin exports (src/media/blackbody_xyz.cpp); `mi` is unused, kept for
    the callers."""
    import ctypes
    from nanovdb_mitsuba import plugin_root
    lib = ctypes.CDLL(os.path.join(plugin_root(), "plugins", "emissiveheterogeneous.so"))
    lib.nvdb_blackbody_xyz.argtypes = [ctypes.c_double, ctypes.POINTER(ctypes.c_double)]
    lib.nvdb_blackbody_xyz.restype = None
    out = (ctypes.c_double * 3)()
    lib.nvdb_blackbody_xyz(float(kelvin), out)
    return list(out)


def blackbody_rgb(mi, kelvin):
    """Linear sRGB of blackbody_xyz()"""
    xyz = blackbody_xyz(mi, kelvin)
    return [sum(m * v for m, v in zip(row, xyz)) for row in _XYZ_TO_SRGB]


def emission_candidates(names, exclude=None):
    """The grid names in `names` that look like emission, in the order of
    preference (EMISSION_NAMES), leaving out `exclude` (the density)"""
    found = [n for n in names if n.lower() in EMISSION_NAMES and n != exclude]
    return sorted(found, key=lambda n: EMISSION_NAMES.index(n.lower()))


def default_density(rows):
    """The grid nanovdb-render reads as the density, of [(name, type)] as
    `vdb2nvdb --list` shows them: a float grid named "density"
    (case-insensitive), else the first float grid (what nanovdbvolume
    reads without a grid name), else "". vdb2nvdb --list marks the same one."""
    for name, vtype in rows:
        if name.lower() == "density" and vtype == "float":
            return name
    return next((name for name, vtype in rows if vtype == "float"), "")


def default_mode(name, vtype="float"):
    """temperature for TEMPERATURE_NAMES, else radiance"""
    return "temperature" if name.lower() in TEMPERATURE_NAMES and vtype == "float" else "radiance"


def find_grid(path, rows, name):
    """`name` in [(name, type)], exactly or else case-insensitively (one
    match); a SystemExit that names the file and lists its grids when absent"""
    names = [n for n, _ in rows]
    if name in names:
        return name
    folded = [n for n in names if n.lower() == name.lower()]
    if len(folded) == 1:
        return folded[0]
    listed = ", ".join(f'"{n}"' for n in names) or "no grids"
    raise SystemExit(f'nanovdb-render: {path}: no grid "{name}" for --emission-grid; '
                     f"the file holds: {listed}")


def choose(path, rows, density, emission_grid=None, mode=None):
    """(grid name, mode) of the emission, or (None, why) without one.
    emission_grid: None (by name, EMISSION_NAMES), "none", or a grid name."""
    if emission_grid is not None and emission_grid.lower() == "none":
        return None, "--emission-grid none"
    types = dict(rows)
    if emission_grid:
        name = find_grid(path, rows, emission_grid)
    else:
        found = emission_candidates([n for n, _ in rows], exclude=density)
        if not found:
            return None, "no grid named " + ", ".join(EMISSION_NAMES)
        name = found[0]
    if mode is None:
        mode = default_mode(name, types.get(name, "float"))
    if mode not in MODES:
        raise SystemExit(f"nanovdb-render: --emission-mode {mode}: choose one of "
                         f"{', '.join(MODES)}")
    if mode == "temperature" and types.get(name) not in (None, "float"):
        raise SystemExit(f'nanovdb-render: {path}: grid "{name}" is a {types[name]} grid: '
                         "temperature mode needs a scalar (float) grid")
    return name, mode


def emission_params(mi, volume, mode, vmax, temperature_scale=None, temperature_offset=None,
                    emission_scale=None, hottest_kelvin=None, brightness=None, cutoff=100.0,
                    channels=None):
    """The emissiveheterogeneous parameters for a loaded emission `volume`
    whose max() is `vmax`, in `mode`; None entries get the defaults of this
    file's docstring. Returns (params, summary, why_not): params None and
    why_not a sentence when the volume cannot emit (empty, or never above
    the cutoff). volume None: the mapping alone (the scales, no volume and
    no colour), e.g. a sequence's from its hottest frame's max. channels
    None: the volume's (1 without one)."""
    hottest_kelvin = HOTTEST_KELVIN if hottest_kelvin is None else hottest_kelvin
    if brightness is None:
        brightness = BRIGHTNESS if mode == "temperature" else FLAME_BRIGHTNESS
    if not vmax > 0.0 and mode == "radiance":
        return None, "", f"its max is {vmax:g}: nothing to emit"
    if channels is None:
        channels = volume.channel_count() if hasattr(volume, "channel_count") else 1
    params = {"emission_scale": 1.0}
    if mode == "temperature":
        offset = 0.0 if temperature_offset is None else float(temperature_offset)
        top = vmax - offset
        if temperature_scale is None:
            if not top > 0.0:
                return None, "", (f"its max ({vmax:g}) is not above the offset ({offset:g}): "
                                  "no value maps to a positive temperature")
            temperature_scale = hottest_kelvin / top
        hottest = top * float(temperature_scale)
        if not hottest > cutoff:
            return None, "", (f"its hottest value maps to {hottest:.4g} K, not above the "
                              f"{cutoff:g} K cutoff")
        y = blackbody_xyz(mi, hottest)[1]
        if emission_scale is None:
            if not y > 1e-12:
                return None, "", (f"its hottest value maps to {hottest:.4g} K, which gives no "
                                  "visible light (raise --temperature-scale)")
            emission_scale = brightness / y
        params.update(temperature_scale=float(temperature_scale), temperature_offset=offset,
                      temperature_cutoff=float(cutoff), emission_scale=float(emission_scale))
        if volume is not None:
            params["temperature"] = volume
        summary = (f"temperature mode, kelvin = (value - {offset:g}) x {temperature_scale:.6g} "
                   f"(max {vmax:.6g} -> {hottest:.0f} K), emission_scale {emission_scale:.4g} "
                   f"(hottest luminance {y * emission_scale:.3g})")
    else:
        if emission_scale is None:
            emission_scale = brightness / vmax
        params.update(emission_scale=float(emission_scale))
        if channels == 3:
            colour = "its own colour (3 channels)"
        else:
            colour = f"a {FIRE_KELVIN:.0f} K blackbody's colour"
        if volume is not None:
            params["emission"] = volume
            if channels != 3:
                params["color"] = {"type": "rgb", "value": list(FIRE_RGB)}
        summary = (f"radiance mode, {colour}, emission_scale {emission_scale:.4g} "
                   f"(max {vmax:.6g} -> luminance {vmax * emission_scale:.3g})")
    return params, summary, None


def emissive_interior(interior, params):
    """`interior` (scene.py's heterogeneous medium dict) as an
    emissiveheterogeneous medium with `params`"""
    out = dict(interior)
    out["type"] = "emissiveheterogeneous"
    out.update(params)
    return out


def fixed_scales(mapping):
    """emission_params()'s keyword arguments for a mapping fixed in advance
    (the "emission" of a sequence's plan, sequence.py: one for all frames):
    its scales, so that nothing is derived from a frame's own max()"""
    out = {k: mapping[k] for k in ("temperature_scale", "temperature_offset", "emission_scale")
           if mapping.get(k) is not None}
    if mapping.get("temperature_cutoff") is not None:
        out["cutoff"] = mapping["temperature_cutoff"]
    return out


def add_emission(mi, scene_dict, nvdb, name, mode, filter_type="trilinear", **scales):
    """Makes scene_dict's medium (its "box" interior) glow with grid `name`
    of `nvdb`, in `mode`, with emission_params(); scales: its overrides
    (None or absent: the defaults, from this grid's max()). Returns
    (rendered, summary, why_not): rendered a dict of what glows (grid, mode,
    max and the scales), or None with why_not a sentence where the grid
    cannot emit (empty, or never above the cutoff): then the scene stays as
    it was. nanovdb-render's single files (render.py) and sequences
    (scene.framed_scene with a plan) both come here."""
    from .facts import volume_facts
    volume = mi.load_dict({"type": "nanovdbvolume", "filename": str(nvdb), "grid": name,
                           "use_grid_transform": True, "filter_type": filter_type})
    facts = volume_facts(volume)
    params, summary, why_not = emission_params(mi, volume, mode, facts["max"], **scales)
    if params is None:
        if facts["index_dims"] == [1, 1, 1] and facts["max"] == 0:
            why_not = "it holds no active voxels"
        return None, summary, why_not
    scene_dict["box"]["interior"] = emissive_interior(scene_dict["box"]["interior"], params)
    return (dict(grid=name, mode=mode, max=facts["max"],
                 **{k: v for k, v in params.items() if isinstance(v, float)}), summary, None)
