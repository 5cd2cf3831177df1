"""Renders nanovdb-render's scene of a .vdb in Blender Cycles (issue 34's
peer benchmark). Runs inside Blender, never in the test command:

    blender -b --factory-startup -P bench/peers/cycles_render.py -- SPEC.json OUT.json

SPEC (written by bench/peers/cycles.py from nanovdb_mitsuba.scene.framed_scene,
so that both renderers see one scene):
    file, grid            the .vdb and its density grid
    scale, albedo         sigma_t = scale x value; sigma_s = albedo sigma_t
    camera                origin, target, fov (degrees, square film), up +y
    sun                   direction of travel, irradiance (RGB, W/m^2)
    sky                   constant radiance (RGB)
    res, max_depth, threads, step_rate
    shift_voxels          the volume moved by this many voxels along each
                          index axis (Cycles places a voxel's value half a
                          voxel away from OpenVDB's convention, which
                          nanovdbvolume follows: -0.5 puts it back)
    renders               a list of {spp, seed, exr}: each rendered and timed

The medium is what Mitsuba's `heterogeneous` with an RGB albedo is: a
Volume Scatter (white, isotropic) of density albedo x scale x value plus a
Volume Absorption (black: sigma_a = density) of (1 - albedo) x scale x
value. What Cycles does differently by default, set here to Mitsuba's
behaviour: volume bounces 0 (here max_depth), max bounces 12, the
indirect clamp 10 (off), adaptive sampling and denoising (off), the Filmic
view (Standard: the EXR holds linear radiance), a 1.5 px Blackman-Harris
filter (a 1 px box, as the Mitsuba side), half-precision grids (full).
The step rate stays a parameter: 1 is Cycles' default.

OUT: per render its wall time (bpy.ops.render.render, which includes
Cycles' scene sync and the volume's upload, every time).
"""
import json
import math
import sys
import time

import bpy
from mathutils import Matrix, Vector


def build(spec):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    cy = sc.cycles
    cy.device = "CPU"
    cy.use_adaptive_sampling = False
    cy.use_denoising = False
    depth = int(spec["max_depth"])
    cy.max_bounces = depth
    cy.volume_bounces = depth
    cy.diffuse_bounces = cy.glossy_bounces = cy.transmission_bounces = depth
    cy.transparent_max_bounces = depth
    cy.sample_clamp_direct = 0.0
    cy.sample_clamp_indirect = 0.0
    cy.caustics_reflective = cy.caustics_refractive = True
    cy.blur_glossy = 0.0
    cy.pixel_filter_type = "BOX"
    cy.filter_width = 1.0
    cy.volume_step_rate = float(spec["step_rate"])
    cy.volume_max_steps = 4096
    sc.view_settings.view_transform = "Standard"
    sc.view_settings.look = "None"
    sc.view_settings.exposure = 0.0
    sc.view_settings.gamma = 1.0
    sc.render.resolution_x = sc.render.resolution_y = int(spec["res"])
    sc.render.resolution_percentage = 100
    sc.render.threads_mode = "FIXED"
    sc.render.threads = int(spec["threads"])
    sc.render.film_transparent = False
    # (persistent data off: with it, Blender 3.4 in background mode returns
    # from every render after the first without rendering)
    sc.render.use_persistent_data = False
    sc.render.image_settings.file_format = "OPEN_EXR"
    sc.render.image_settings.color_depth = "32"
    sc.render.image_settings.color_mode = "RGB"

    # Sky: a constant background
    world = bpy.data.worlds.new("sky")
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (*spec["sky"], 1.0)
    bg.inputs["Strength"].default_value = 1.0
    sc.world = world

    # Sun: Mitsuba's directional emitter (its direction is the light's travel)
    sun = bpy.data.lights.new("sun", "SUN")
    irr = spec["sun"]["irradiance"]
    peak = max(irr)
    sun.energy = peak
    sun.color = tuple(c / peak for c in irr)
    sun.angle = 0.0
    sun_obj = bpy.data.objects.new("sun", sun)
    sun_obj.rotation_euler = Vector(spec["sun"]["direction"]).to_track_quat("-Z", "Y").to_euler()
    sc.collection.objects.link(sun_obj)

    # Camera: Mitsuba's look_at with up +y (Blender's camera looks along its
    # local -Z with +Y up)
    cam = bpy.data.cameras.new("camera")
    cam.sensor_fit = "HORIZONTAL"
    cam.angle = math.radians(spec["camera"]["fov"])
    cam.clip_start = 1e-4
    cam.clip_end = 1e6
    cam_obj = bpy.data.objects.new("camera", cam)
    o, t = Vector(spec["camera"]["origin"]), Vector(spec["camera"]["target"])
    f = (t - o).normalized()
    r = f.cross(Vector((0.0, 1.0, 0.0))).normalized()
    u = r.cross(f)
    m = Matrix.Identity(4)
    for i in range(3):
        m[i][0], m[i][1], m[i][2], m[i][3] = r[i], u[i], -f[i], o[i]
    cam_obj.matrix_world = m
    sc.collection.objects.link(cam_obj)
    sc.camera = cam_obj

    # The volume, in the .vdb's own world space (its grid transform)
    vol = bpy.data.volumes.new("volume")
    vol.filepath = spec["file"]
    vol.render.precision = "FULL"
    vol.grids.load()
    names = [g.name for g in vol.grids]
    if spec["grid"] not in names:
        raise SystemExit(f"cycles_render: no grid {spec['grid']!r} in {spec['file']} ({names})")
    vol_obj = bpy.data.objects.new("volume", vol)
    grid = vol.grids[spec["grid"]]
    g = grid.matrix_object  # index -> object space
    half = float(spec["shift_voxels"])
    shift = (g @ Vector((half, half, half))) - (g @ Vector((0.0, 0.0, 0.0)))
    vol_obj.location = shift
    sc.collection.objects.link(vol_obj)

    mat = bpy.data.materials.new("medium")
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    attr = nt.nodes.new("ShaderNodeAttribute")
    attr.attribute_name = spec["grid"]
    scale, albedo = float(spec["scale"]), float(spec["albedo"])
    scatter = nt.nodes.new("ShaderNodeVolumeScatter")
    scatter.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    scatter.inputs["Anisotropy"].default_value = 0.0
    absorb = nt.nodes.new("ShaderNodeVolumeAbsorption")
    absorb.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    add = nt.nodes.new("ShaderNodeAddShader")
    for node, k in ((scatter, albedo * scale), (absorb, (1.0 - albedo) * scale)):
        mul = nt.nodes.new("ShaderNodeMath")
        mul.operation = "MULTIPLY"
        mul.inputs[1].default_value = k
        nt.links.new(attr.outputs["Fac"], mul.inputs[0])
        nt.links.new(mul.outputs["Value"], node.inputs["Density"])
    nt.links.new(scatter.outputs["Volume"], add.inputs[0])
    nt.links.new(absorb.outputs["Volume"], add.inputs[1])
    nt.links.new(add.outputs["Shader"], out.inputs["Volume"])
    vol_obj.data.materials.append(mat)
    return sc


def main():
    argv = sys.argv[sys.argv.index("--") + 1:]
    with open(argv[0]) as f:
        spec = json.load(f)
    sc = build(spec)
    results = []
    for r in spec["renders"]:
        sc.cycles.samples = int(r["spp"])
        sc.cycles.seed = int(r["seed"])
        t0 = time.perf_counter()
        bpy.ops.render.render()
        seconds = time.perf_counter() - t0
        bpy.data.images["Render Result"].save_render(r["exr"])
        results.append(dict(spp=r["spp"], seed=r["seed"], exr=r["exr"], time_s=seconds))
        print(f"cycles_render: {r['spp']} spp, seed {r['seed']}: {seconds:.3f} s", flush=True)
    with open(argv[1], "w") as f:
        json.dump({"renders": results, "blender": bpy.app.version_string}, f, indent=1)


if __name__ == "__main__":
    main()
