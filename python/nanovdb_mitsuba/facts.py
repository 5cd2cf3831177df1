"""What a loaded nanovdbvolume is, read through mi.traverse: the plugin
exposes its facts as non-differentiable parameters (Mitsuba's Python side
carries numbers and arrays, not strings: the grid type and class arrive as
NanoVDB's codes and are named here)."""

# NanoVDB's GridType and GridClass codes (PNANOVDB_GRID_TYPE_*, _CLASS_*)
GRID_TYPES = ["unknown", "float", "double", "int16", "int32", "int64", "Vec3f", "Vec3d",
              "Mask", "Half", "uint32", "bool", "RGBA8", "Fp4", "Fp8", "Fp16", "FpN", "Vec4f",
              "Vec4d", "Index", "OnIndex", "IndexMask", "OnIndexMask", "PointIndex", "Vec3u8",
              "Vec3u16", "UInt8"]
GRID_CLASSES = ["unknown", "level set", "fog volume", "staggered", "point index",
                "point data", "topology", "voxel volume", "index grid", "tensor grid"]

COUNTERS = ["lookup_count", "walk_step_count", "walk_empty_step_count", "walk_step_8_count",
            "walk_step_32_count", "walk_step_128_count", "walk_step_4096_count", "walk_count"]


def _name(table, code):
    code = int(code)
    return table[code] if 0 <= code < len(table) else f"unknown ({code})"


def volume_facts(volume):
    """A dict of a nanovdbvolume's facts, plain Python values:

    grid_index (the grid's position in its file; None for volumes from
    memory), grid_type and grid_class (names), channels, index_min and
    index_dims (the volume's index box: [x, y, z] lists), world_bbox_min and
    world_bbox_max, max (what lookups return at most), grid_max (the largest
    value the grid stores), background, local_majorant_ratio, grid_bytes,
    backend_bytes, majorant_bytes, spectral_scale_bytes, wrap_mode ("clamp"
    or "tree"), majorant_rebuild ("backend": a differentiable volume's
    majorants follow its updates there; "host"), majorant_rebuild_replays
    (backend rebuilds that replayed the first one's kernels), and with
    count_lookups=True
    the counters (lookup_count, walk_step_count, ...)."""
    import mitsuba as mi
    p = mi.traverse(volume)

    def vec(key, cast):
        v = p[key]
        return [cast(v[k]) for k in range(3)]

    facts = {
        "grid_index": None if int(p["grid_index"]) == 0xFFFFFFFF else int(p["grid_index"]),
        "grid_type": _name(GRID_TYPES, p["grid_type"]),
        "grid_class": _name(GRID_CLASSES, p["grid_class"]),
        "channels": int(p["channels"]),
        "index_min": vec("index_min", int),
        "index_dims": vec("index_dims", int),
        "world_bbox_min": vec("world_bbox_min", float),
        "world_bbox_max": vec("world_bbox_max", float),
        "wrap_mode": "clamp" if p["wrap_clamp"] else "tree",
        "majorant_rebuild": "backend" if p["majorant_rebuild_on_backend"] else "host",
        "majorant_rebuild_replays": int(p["majorant_rebuild_replays"]),
    }
    for key in ("max", "grid_max", "background", "local_majorant_ratio"):
        facts[key] = float(p[key])
    for key in ("grid_bytes", "backend_bytes", "majorant_bytes", "spectral_scale_bytes"):
        facts[key] = int(p[key])
    for key in COUNTERS:
        if key in p:
            facts[key] = int(p[key])
    return facts


def integrator_facts(integrator):
    """volpathlocal's facts: tracked_media (how many media the last render
    tracked through the walk) and loop_bound_trips (lanes its loop bounds
    stopped so far: 0 unless something is wrong)."""
    import mitsuba as mi
    p = mi.traverse(integrator)
    return {key: int(p[key]) for key in ("tracked_media", "loop_bound_trips") if key in p}
