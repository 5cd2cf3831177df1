"""Animated sequences in nanovdb-render: one volume file per frame.

    nanovdb-render 'smoke.####.vdb' -o out.png [--frames 10-120:2]
        [--plan plan.json] [--shard I/N] [--overwrite] [--video out.mp4]

The input names the frames with a run of '#' (smoke.####.vdb), a printf
field (smoke.%04d.vdb) or a folder of numbered .vdb/.nvdb files. Every frame
is rendered with one camera, fitted to the union of all frames' world boxes,
and one density scale: the median over the frames that hold voxels of the
scale nanovdb-render would choose for each frame alone (scene.default_scale,
from the plugin's per-node density bounds), so that nothing jumps or
flickers and one odd frame does not decide it. That union and that scale
come from a scan of every frame, summarised in a plan (a small JSON file,
plan_json()); with --plan FILE an existing plan is read instead of
scanning, so that the shards of a render farm (--shard I/N: every N-th
selected frame from the I-th) agree on camera and scale without reading
each other's frames.

Frames: out.0010.png (sRGB) and out.0010.exr (linear), each written when it
is done (under a temporary name, then renamed), so that a re-run skips the
frames already written (--overwrite renders them again). A missing file is
reported in one line and skipped: no image is written, so a later run
renders it once the file exists (the video, if any, shows a black frame in
its place). A frame whose grid holds no voxels (or lacks the grid) is
reported and rendered as what it is: the sky and the sun without a volume.
A frame that cannot be read is reported and skipped like a missing one.

The parts: frames.py (the pattern, --frames, --shard, the images' names),
plan.py (the scan and the plan), this file (each frame's scene, the render
loop, the video, the command line).

Fire: the scan also picks the emission grid a single file would glow with
(fire.py's names, or --emission-grid; the one most frames would choose) and
records each frame's emission max. One mapping serves every frame, so that
the fire does not flicker: temperature mode's temperature_scale maps the
largest max over the frames to fire.HOTTEST_KELVIN, and one emission_scale
(that temperature's luminance fire.BRIGHTNESS; in radiance mode, the
largest max's luminance fire.FLAME_BRIGHTNESS). It is stored in the plan
("emission"), so that every shard renders with the same. A frame without
the grid, or whose grid is empty, renders without emission and says so in
its line.
"""
import json
import os
import sys
import time

from nanovdb_mitsuba import files, setup
from nanovdb_mitsuba.frames import (FrameError, _ranges, is_sequence, output_pattern,
                                    parse_frames, parse_pattern, parse_shard, shard_frames,
                                    written)
from nanovdb_mitsuba.plan import (EMISSION_OPTIONS, emission_line, load_frame, read_plan, scan,
                                  summary_line, write_plan)
from nanovdb_mitsuba.scene import framed_scene

# A frame's scene, the same on every shard

def frame_scene(mi, plan, volume_file, res, spp, integrator, filter_type, emission_grid=None,
                volume=None):
    """(scene dict, info) of a plan's frame: framed_scene with the plan's
    camera, scale, albedo and fire (emission_grid: its name in this frame,
    or "none"); volume_file None (an empty frame): no box, the lights;
    volume: the frame's volume, if already loaded (load_frame)"""
    return framed_scene(mi, volume_file, grid=plan["grid"], sequence=plan, res=res, spp=spp,
                        integrator=integrator, filter_type=filter_type,
                        emission_grid=emission_grid, volume=volume)


def scene_json(scene, entry, grid, emission_grid=None):
    """A scene dict as JSON text (sorted keys): transforms as their
    matrices, the volumes as the frame's file and grid (the emission's,
    under "temperature" or "emission", as emission_grid), so that shards
    compare byte for byte"""
    import numpy as np

    def plain(v, key=None):
        if isinstance(v, dict):
            return {k: plain(x, k) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        if isinstance(v, (str, int, float, bool)) or v is None:
            return v
        if type(v).__name__.startswith("ScalarTransform4"):
            return {"matrix": np.array(v.matrix).tolist()}
        if "Volume" in type(v).__name__:
            g = emission_grid if key in ("temperature", "emission") and emission_grid else grid
            return {"type": "nanovdbvolume", "file": entry["file"], "grid": g,
                    "use_grid_transform": True}
        return str(v)
    return json.dumps(plain(scene), sort_keys=True, indent=1) + "\n"


# Rendering

def write_frame(mi, image, png):
    """PNG (sRGB) and EXR (linear), each under a temporary name first, so
    that an interrupted frame is never taken for a written one"""
    bitmap = mi.Bitmap(image)
    stem = os.path.splitext(png)[0]
    part = f"{stem}.part{os.getpid()}"
    bitmap.write(part + ".exr")
    bitmap.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True).write(
        part + ".png")
    os.replace(part + ".exr", stem + ".exr")  # the EXR first: the PNG completes the frame
    os.replace(part + ".png", png)


def render_sequence(spec, output=None, frames=None, shard=None, plan_path=None, overwrite=False,
                    video=None, grid="", spp=64, res=256, variant="llvm_ad_rgb",
                    integrator="volpathlocal", scale=None, filter_type="trilinear",
                    scene_json_dir=None, log=print, emission_grid=None, emission_mode=None,
                    temperature_scale=None, temperature_offset=None, emission_scale=None):
    """Renders the frames of `spec` (see the module's doc). frames: a list
    of frame numbers (default: from the first to the last file found, or the
    plan's); shard (I, N); plan_path: read the plan there if it exists,
    else scan, write it there and return without rendering. The fire
    options as render_file's (emission_grid "none": no emission; with a
    plan, the others must be the plan's). Returns a dict: plan, rendered /
    skipped / missing / empty / failed frame lists, the frames rendered
    without their emission ("no_emission": {frame: why}), seconds."""
    import mitsuba as mi
    import drjit as dr
    import numpy as np
    mi.set_variant(variant)
    setup(mi)
    pattern = parse_pattern(spec)
    options = dict(emission_grid=emission_grid, emission_mode=emission_mode,
                   temperature_scale=temperature_scale, temperature_offset=temperature_offset,
                   emission_scale=emission_scale)
    no_emission = emission_grid is not None and emission_grid.lower() == "none"
    plan = None
    if plan_path and os.path.exists(plan_path):
        plan = read_plan(plan_path)
        if grid and grid != plan["grid"]:
            raise SystemExit(f"nanovdb-render: --grid \"{grid}\" but the plan \"{plan_path}\" "
                             f"renders grid \"{plan['grid']}\"")
        if scale is not None and scale != plan["scale"]:
            raise SystemExit(f"nanovdb-render: --scale {scale:g} but the plan \"{plan_path}\" "
                             f"has scale {plan['scale']:g}: write a new plan with --scale")
        # The fire is the plan's: an option given now must be the one it
        # was scanned with (--no-emission only switches it off)
        scanned = plan.get("emission_options", {})
        for k, v in options.items():
            if v is None or (k == "emission_grid" and v.lower() == "none"):
                continue
            if scanned.get(k) != v:
                flag = "--" + k.replace("_", "-")
                was = f"{flag} {scanned[k]}" if k in scanned else f"no {flag}"
                raise SystemExit(f"nanovdb-render: {flag} {v} but the plan \"{plan_path}\" was "
                                 f"written with {was} (one fire for all shards): write a new "
                                 f"plan with {flag}")
        by_frame = {e["frame"]: e for e in plan["frames"]}
        if frames is not None:
            outside = [f for f in frames if f not in by_frame]
            if outside:
                raise SystemExit(f"nanovdb-render: frames {_ranges(outside)} are not in the plan "
                                 f"\"{plan_path}\" ({_ranges(list(by_frame))})")
    elif shard is not None:
        raise SystemExit("nanovdb-render: --shard needs an existing plan (--plan FILE): write it "
                         "first with one run of the same command without --shard, so that the "
                         "shards share one camera and scale")
    if plan is None:
        if frames is None:
            found = pattern.found()
            if not found:
                raise SystemExit(f"nanovdb-render: \"{spec}\": no files match {pattern.text}")
            frames = list(range(min(found), max(found) + 1))
        log(f"{pattern.text}: scanning {len(frames)} frames for their boxes and scales")
        plan = scan(mi, pattern, frames, grid=grid, scale=scale, filter_type=filter_type,
                    log=log, **options)
        log(summary_line(plan))
        log(emission_line(plan))
        if plan_path:
            write_plan(plan, plan_path)
            log(f"wrote the plan {plan_path}; render with --plan {plan_path} "
                "[--shard I/N] (nothing rendered yet)")
            return dict(plan=plan, rendered=[], skipped=[], missing=[], empty=[], failed=[],
                        no_emission={}, seconds=0.0)
    else:
        log(summary_line(plan))
        log(emission_line(plan, rendered=not no_emission))
    glow = plan.get("emission") if not no_emission else None
    if glow and integrator != "volpathlocal":
        raise SystemExit(f"nanovdb-render: {pattern.text}: grid \"{glow['grid']}\" emits light, "
                         f"which only the volpathlocal integrator renders, not {integrator}; "
                         "leave --integrator out, or add --no-emission")
    entries = [e for e in plan["frames"] if frames is None or e["frame"] in frames]
    if shard is not None:
        entries = shard_frames(entries, shard)
    outpat = output_pattern(output, pattern)
    if os.path.dirname(outpat.prefix):
        os.makedirs(os.path.dirname(outpat.prefix), exist_ok=True)
    result = dict(plan=plan, rendered=[], skipped=[], missing=[], empty=[], failed=[],
                  no_emission={})
    todo = [e for e in entries if overwrite or not written(outpat.path(e["frame"]))]
    skipped = [e["frame"] for e in entries if e not in todo]
    result["skipped"] = skipped
    if skipped:
        log(f"{len(skipped)} frames already written ({_ranges(skipped)}): skipped"
            " (--overwrite renders them again)")
    started = time.perf_counter()
    times = []
    for i, entry in enumerate(todo):
        f = entry["frame"]
        t0 = time.perf_counter()
        head = f"frame {f} [{i + 1}/{len(todo)}]"
        # The file as it is now, on this machine (the plan may be older)
        path = pattern.path(f)
        try:
            status, why, volume, held = load_frame(mi, path, plan["grid"], filter_type,
                                                   emission=glow["grid"] if glow else None)
        except FrameError as e:
            status, why, volume, held = "error", str(e), None, None
        if status in ("missing", "error"):
            result["missing" if status == "missing" else "failed"].append(f)
            log(f"{head}: {path}: {why}: skipped, no image written")
            continue
        scene, info = frame_scene(mi, plan, path if status == "ok" else None, res, spp,
                                  integrator, filter_type,
                                  emission_grid=held if glow and held else "none",
                                  volume=volume if status == "ok" else None)
        del volume
        dark = None  # why this frame renders without its emission
        if glow and status == "ok":
            if not held:
                dark = f'no grid "{glow["grid"]}"'
            elif info.get("emission") is None:
                dark = f'grid "{held}" is empty: {info.get("emission_why_not", "")}'
        if dark:
            result["no_emission"][f] = dark
        png = outpat.path(f)
        if scene_json_dir is not None:
            name = os.path.splitext(os.path.basename(png))[0] + ".scene.json"
            with open(os.path.join(scene_json_dir, name), "w") as fh:
                fh.write(scene_json(scene, dict(entry, file=path), plan["grid"], held))
        img = mi.render(mi.load_dict(scene), spp=spp, seed=f)
        dr.eval(img)
        write_frame(mi, np.array(img, dtype=np.float32), png)
        del scene, info, img
        dt = time.perf_counter() - t0
        times.append(dt)
        left = len(todo) - i - 1
        eta = sum(times) / len(times) * left
        what = "" if status == "ok" else f" ({why}: the sky and the sun only)"
        if dark:
            what = f" (without emission: {dark})"
        result["rendered" if status == "ok" else "empty"].append(f)
        log(f"{head}: wrote {png}{what} in {dt:.1f} s; {left} to go, about {eta:.0f} s left")
    result["seconds"] = time.perf_counter() - started
    n = len(result["rendered"]) + len(result["empty"])
    log(f"rendered {n} frames in {result['seconds']:.1f} s ({res}x{res}, {spp} spp, {variant})"
        + (f"; shard {shard[0]}/{shard[1]}" if shard else ""))
    if video:
        if shard is not None:
            log(f"video {video}: not written by a shard; run the same command without --shard "
                "after the shards (it renders nothing new) to encode it")
        else:
            write_video(video, [outpat.path(e["frame"]) for e in plan["frames"]
                                if frames is None or e["frame"] in frames], res, log)
    return result


def write_video(path, pngs, res, log=print, fps=24):
    """The frames as a video where an encoder is importable (imageio with
    imageio-ffmpeg for .mp4 and the like, Pillow for .gif); one line and
    nothing written otherwise. A frame without a PNG is black."""
    import numpy as np
    frames = []

    def read(p):
        if not os.path.exists(p):
            return None
        try:
            from PIL import Image
            return np.asarray(Image.open(p).convert("RGB"))
        except ImportError:
            import mitsuba as mi
            return np.array(mi.Bitmap(p))[..., :3]
    for p in pngs:
        frames.append(read(p))
    shape = next((f.shape for f in frames if f is not None), (res, res, 3))
    frames = [f if f is not None else np.zeros(shape, np.uint8) for f in frames]
    if path.lower().endswith(".gif"):
        try:
            from PIL import Image
        except ImportError:
            log(f"video {path}: skipped (a GIF needs Pillow, which is not installed)")
            return None
        ims = [Image.fromarray(f) for f in frames]
        ims[0].save(path, save_all=True, append_images=ims[1:], duration=int(1000 / fps), loop=0)
    else:
        try:
            import imageio.v2 as imageio
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            log(f"video {path}: skipped (no encoder: pip install imageio imageio-ffmpeg, or "
                "ask for a .gif)")
            return None
        with imageio.get_writer(path, fps=fps) as w:
            for f in frames:
                w.append_data(f)
    log(f"wrote the video {path} ({len(frames)} frames, {fps} fps)")
    return path


# The command line (render.py's main() hands sequences over)

def add_arguments(ap):
    g = ap.add_argument_group(
        "sequences", "INPUT 'smoke.####.vdb', 'smoke.%04d.vdb' or a folder of numbered files "
        "renders every frame (out.0001.png ...) with one camera, one density scale and one fire "
        "mapping (the emission scales from the largest emission max over the frames)")
    g.add_argument("--frames", metavar="A-B[:S]", help="the frames to render: 10-120, 10-120:2, "
                   "7, 1-5,9 (default: from the first file to the last)")
    g.add_argument("--shard", metavar="I/N", help="render every N-th frame from the I-th (0-based), "
                   "e.g. $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT; needs --plan")
    g.add_argument("--plan", metavar="FILE", help="the sequence's summary (JSON: union box, "
                   "scale, fire mapping, frames): read if FILE exists, else scan, write FILE "
                   "and stop")
    g.add_argument("--overwrite", action="store_true",
                   help="render frames whose PNG and EXR exist (default: skip them)")
    g.add_argument("--video", metavar="FILE", help="encode the frames at the end (.mp4 needs "
                   "imageio-ffmpeg, .gif Pillow; skipped with a note without them)")
    g.add_argument("--scene-json", metavar="DIR", help="write each frame's scene dict as JSON "
                   "(out.0010.scene.json) into DIR")


SEQUENCE_OPTIONS = ("frames", "shard", "plan", "overwrite", "video", "scene_json")


def handles(a, ap):
    """For render.py's main(): renders a sequence and returns True, or
    False for a single file (an error if sequence options were given)"""
    if not is_sequence(a.input):
        used = [o for o in SEQUENCE_OPTIONS if getattr(a, o, None)]
        if used:
            ap.error(f"--{used[0].replace('_', '-')} is for sequences ('smoke.####.vdb', "
                     "'smoke.%04d.vdb' or a folder); the input is one file")
        return False
    try:
        frames = parse_frames(a.frames) if a.frames else None
        shard = parse_shard(a.shard) if a.shard else None
    except ValueError as e:
        ap.error(str(e))
    if a.scene_json:
        os.makedirs(a.scene_json, exist_ok=True)
    try:
        render_sequence(a.input, output=a.output, frames=frames, shard=shard, plan_path=a.plan,
                        overwrite=a.overwrite, video=a.video, grid=a.grid, spp=a.spp, res=a.res,
                        variant=a.variant, integrator=a.integrator, scale=a.scale,
                        filter_type=a.filter, scene_json_dir=a.scene_json,
                        log=lambda s: print(s, flush=True),
                        **{k: getattr(a, k, None) for k in EMISSION_OPTIONS})
    except RuntimeError as e:  # (files.FileError too)
        raise SystemExit(f"nanovdb-render: {files.plugin_message(e)}")
    return True


if __name__ == "__main__":
    sys.exit("run nanovdb-render (python -m nanovdb_mitsuba.render) with 'name.####.vdb'")
