"""Animated sequences in nanovdb-render: one volume file per frame.

    nanovdb-render 'smoke.####.vdb' -o out.png [--frames 10-120:2]
        [--plan plan.json] [--shard I/N] [--overwrite] [--video out.mp4]

The input names the frames with a run of '#' (smoke.####.vdb), a printf
field (smoke.%04d.vdb) or a folder of numbered .vdb/.nvdb files. Every frame
is rendered with one camera, fitted to the union of all frames' world boxes,
and one density scale: the median over the frames that hold voxels of the
scale nanovdb-render would choose for each frame alone (scene.default_scale,
a mean optical depth of about 8), so that nothing jumps or flickers and one
odd frame does not decide it. That union and that scale come from a scan of
every frame, summarised in a plan (a small JSON file, plan_json()); with
--plan FILE an existing plan is read instead of scanning, so that the shards
of a render farm (--shard I/N: every N-th selected frame from the I-th) agree
on camera and scale without reading each other's frames.

Frames: out.0010.png (sRGB) and out.0010.exr (linear), each written when it
is done (under a temporary name, then renamed), so that a re-run skips the
frames already written (--overwrite renders them again). A missing file is
reported in one line and skipped: no image is written, so a later run
renders it once the file exists (the video, if any, shows a black frame in
its place). A frame whose grid holds no voxels (or lacks the grid) is
reported and rendered as what it is: the sky and the sun without a volume.
A frame that cannot be read is reported and skipped like a missing one.
"""
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time

from nanovdb_mitsuba import setup, vdb2nvdb
from nanovdb_mitsuba.facts import volume_facts
from nanovdb_mitsuba.scene import framed_scene

PLAN_VERSION = 1
SCALE_RULE = "median over the frames with voxels of each frame's default scale"

# '####' or '%04d' / '%d' in a file name
_TOKEN = re.compile(r"#+|%(0?\d*)d")
_FRAME_FILE = re.compile(r"^(.*?)(\d+)(\.n?vdb)$", re.IGNORECASE)


class FrameError(Exception):
    """A frame that cannot be read: reported in one line, never a stop"""


class Pattern:
    """A file name with a frame number in it: prefix, the number padded with
    zeros to `width` digits, suffix. `text` is the pattern as '#'s."""

    def __init__(self, prefix, width, suffix):
        self.prefix, self.width, self.suffix = prefix, max(1, width), suffix

    @property
    def text(self):
        return self.prefix + "#" * self.width + self.suffix

    def path(self, frame):
        return f"{self.prefix}{frame:0{self.width}d}{self.suffix}"

    def found(self):
        """{frame: path} of the files present on disk that match"""
        folder = os.path.dirname(self.prefix) or "."
        base = os.path.basename(self.prefix)
        rx = re.compile("^" + re.escape(base) + r"(\d{%d,})" % self.width +
                        re.escape(self.suffix) + "$")
        frames = {}
        try:
            names = os.listdir(folder)
        except OSError:
            return frames
        for name in names:
            m = rx.match(name)
            if m and (len(m.group(1)) == self.width or not m.group(1).startswith("0")):
                frames[int(m.group(1))] = os.path.join(os.path.dirname(self.prefix), name)
        return frames


def is_sequence(spec):
    """True for 'smoke.####.vdb', 'smoke.%04d.vdb' or a folder"""
    return os.path.isdir(spec) or bool(_TOKEN.search(os.path.basename(spec)))


def parse_pattern(spec):
    """Pattern of a '#' or '%0Nd' file name, or of a folder's numbered
    .vdb/.nvdb files (the largest group sharing a prefix and suffix)"""
    if os.path.isdir(spec):
        groups = {}
        for name in sorted(os.listdir(spec)):
            m = _FRAME_FILE.match(name)
            if m:
                groups.setdefault((m.group(1), m.group(3)), []).append(m.group(2))
        if not groups:
            raise SystemExit(f"nanovdb-render: \"{spec}\": no numbered .vdb or .nvdb files "
                             "(name.0001.vdb ...) in this folder")
        (prefix, suffix), digits = max(groups.items(), key=lambda kv: len(kv[1]))
        return Pattern(os.path.join(spec, prefix), min(len(d) for d in digits), suffix)
    folder, base = os.path.split(spec)
    tokens = list(_TOKEN.finditer(base))
    if len(tokens) != 1:
        raise SystemExit(f"nanovdb-render: \"{spec}\": one frame number field please "
                         "('####' or '%04d'), not several")
    m = tokens[0]
    if m.group(0).startswith("#"):
        width = len(m.group(0))
    else:
        width = int(m.group(1) or "1")
    return Pattern(os.path.join(folder, base[:m.start()]), width, base[m.end():])


def parse_frames(text):
    """'10-120', '10-120:2', '7', '1-5,9,20-30:5' -> sorted frame numbers"""
    frames = set()
    for part in text.split(","):
        m = re.fullmatch(r"\s*(\d+)(?:\s*-\s*(\d+))?(?:\s*:\s*(\d+))?\s*", part)
        if not m or (m.group(3) and int(m.group(3)) < 1):
            raise ValueError(f"--frames: \"{part}\" is not FIRST-LAST[:STEP] or a frame number")
        first = int(m.group(1))
        last = int(m.group(2)) if m.group(2) else first
        if last < first:
            raise ValueError(f"--frames: \"{part}\" ends before it starts")
        frames.update(range(first, last + 1, int(m.group(3) or 1)))
    return sorted(frames)


def parse_shard(text):
    """'I/N' -> (I, N), 0 <= I < N"""
    m = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", text or "")
    if not m or not 0 <= int(m.group(1)) < int(m.group(2)):
        raise ValueError(f"--shard: \"{text}\" is not I/N with 0 <= I < N (e.g. "
                         "$SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT)")
    return int(m.group(1)), int(m.group(2))


def shard_frames(frames, shard):
    """Every N-th of `frames` from the I-th: the shards partition them"""
    i, n = shard
    return frames[i::n]


# The frames' files: vdb2nvdb lists and converts them

def list_grids(path):
    """[(name, type)] of a file's grids, as vdb2nvdb --list shows them;
    FrameError if it cannot read the file"""
    r = subprocess.run([vdb2nvdb(), "--list", path], stdout=subprocess.PIPE,
                       stderr=subprocess.STDOUT, text=True)
    if r.returncode != 0:
        lines = r.stdout.strip().splitlines() or [f"vdb2nvdb --list failed ({r.returncode})"]
        raise FrameError(lines[-1])
    rows = []
    for line in r.stdout.splitlines():
        m = re.match(r'^\s+(\d+)\s+"(.*)"\s+(\S+)', line)
        if m and int(m.group(1)) == len(rows):
            rows.append((m.group(2), m.group(3)))
    return rows


def default_grid(rows):
    """The grid nanovdb-render renders of a file: a float grid named
    "density", else the first float grid, else the first grid"""
    for name, vtype in rows:
        if name.lower() == "density" and vtype == "float":
            return name
    floats = [name for name, vtype in rows if vtype == "float"]
    return floats[0] if floats else (rows[0][0] if rows else "")


def convert(path, grid, tmpdir):
    """Grid `grid` of `path` into a .nvdb in tmpdir (vdb2nvdb: a level set
    becomes a fog volume); FrameError with vdb2nvdb's message"""
    out = os.path.join(tmpdir, os.path.basename(path) + ".nvdb")
    r = subprocess.run([vdb2nvdb(), path, out, "--verify", "0", "--grid", grid],
                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if r.returncode != 0:
        lines = r.stdout.strip().splitlines() or [f"vdb2nvdb failed ({r.returncode})"]
        raise FrameError(lines[-1])
    return out


def load_frame(mi, path, grid, tmpdir, filter_type="trilinear"):
    """(status, why, volume, nvdb) of one frame: status "ok" (volume loaded,
    nvdb the file it reads), "empty" (no such grid, or no positive value)
    or "missing"; FrameError where the file cannot be read"""
    if not os.path.exists(path):
        return "missing", "no such file", None, None
    rows = list_grids(path)
    if grid not in [n for n, _ in rows]:
        listed = ", ".join(f'"{n}"' for n, _ in rows) or "no grids"
        return "empty", f'no grid "{grid}" (the file holds {listed})', None, None
    nvdb = convert(path, grid, tmpdir) if path.lower().endswith(".vdb") else path

    def load(f):
        try:
            return mi.load_dict({"type": "nanovdbvolume", "filename": f, "grid": grid,
                                 "use_grid_transform": True, "filter_type": filter_type})
        except RuntimeError as e:
            raise FrameError(str(e).rsplit("[NanoVDBVolume] ", 1)[-1].strip())
    volume = load(nvdb)
    facts = volume_facts(volume)
    if facts["grid_class"] == "level set" and nvdb == path:
        # A .nvdb level set: made a fog volume, as a .vdb's is
        del volume
        nvdb = convert(path, grid, tmpdir)
        volume = load(nvdb)
        facts = volume_facts(volume)
    if not facts["max"] > 0.0:
        why = ("holds no active voxels" if facts["index_dims"] == [1, 1, 1]
               else "holds no positive density")
        return "empty", f'grid "{grid}" {why}', None, None
    return "ok", "", volume, nvdb


# The plan: what every shard must agree on

def scan(mi, pattern, frames, grid="", scale=None, filter_type="trilinear", log=print):
    """The plan of `frames` of `pattern` (a dict, see plan_json): every frame
    read once for its status, world box and default scale"""
    from nanovdb_mitsuba.scene import default_scale
    if not grid:
        # The density most frames would be rendered with alone
        votes = {}
        for f in frames:
            path = pattern.path(f)
            if os.path.exists(path):
                try:
                    name = default_grid(list_grids(path))
                except FrameError:
                    continue
                if name:
                    votes[name] = votes.get(name, 0) + 1
        grid = max(votes, key=votes.get) if votes else "density"
    entries = []
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for i, f in enumerate(frames):
            entry = {"frame": f, "file": pattern.path(f)}
            try:
                status, why, volume, nvdb = load_frame(mi, entry["file"], grid, tmp, filter_type)
            except FrameError as e:
                status, why, volume, nvdb = "error", str(e), None, None
            entry["status"] = status
            if why:
                entry["why"] = why
            if volume is not None:
                bb = volume.bbox()
                entry["bbox_min"] = [float(x) for x in bb.min]
                entry["bbox_max"] = [float(x) for x in bb.max]
                entry["scale"] = float(default_scale(volume))
                del volume
                if nvdb != entry["file"]:
                    os.remove(nvdb)
            entries.append(entry)
            if len(frames) > 20 and (i + 1) % 20 == 0:
                log(f"scanned {i + 1}/{len(frames)} frames, {time.perf_counter() - started:.1f} s")
    ok = [e for e in entries if e["status"] == "ok"]
    if not ok:
        raise SystemExit(f"nanovdb-render: {pattern.text}: none of the {len(frames)} frames "
                         f"holds voxels in grid \"{grid}\" ("
                         + ", ".join(sorted({e['status'] for e in entries})) + ")")
    plan = {
        "nanovdb_sequence": PLAN_VERSION,
        "pattern": pattern.text,
        "grid": grid,
        "frames": entries,
        "bbox_min": [min(e["bbox_min"][k] for e in ok) for k in range(3)],
        "bbox_max": [max(e["bbox_max"][k] for e in ok) for k in range(3)],
        "scale": float(scale) if scale is not None else float(
            statistics.median(e["scale"] for e in ok)),
        "scale_rule": "--scale" if scale is not None else SCALE_RULE,
    }
    return plan


def plan_json(plan):
    """The plan as written to disk: sorted keys, one frame a line"""
    head = {k: v for k, v in plan.items() if k != "frames"}
    text = json.dumps(head, sort_keys=True, indent=1)[:-2]
    frames = ",\n  ".join(json.dumps(e, sort_keys=True) for e in plan["frames"])
    return text + ',\n "frames": [\n  ' + frames + "\n ]\n}\n"


def write_plan(plan, path):
    tmp = f"{path}.{os.getpid()}.tmp"
    with open(tmp, "w") as f:
        f.write(plan_json(plan))
    os.replace(tmp, path)


def read_plan(path):
    try:
        with open(path) as f:
            plan = json.load(f)
    except (OSError, ValueError) as e:
        raise SystemExit(f"nanovdb-render: plan \"{path}\": {e}")
    missing = [k for k in ("nanovdb_sequence", "pattern", "grid", "frames", "bbox_min",
                           "bbox_max", "scale") if k not in plan]
    if missing or plan.get("nanovdb_sequence") != PLAN_VERSION:
        raise SystemExit(f"nanovdb-render: plan \"{path}\": not a version-{PLAN_VERSION} "
                         f"sequence plan (missing: {', '.join(missing) or 'none'})")
    return plan


def summary_line(plan):
    by = {}
    for e in plan["frames"]:
        by.setdefault(e["status"], []).append(e["frame"])
    counts = ", ".join(f"{len(v)} {k}" + ("" if k == "ok" else f" ({_ranges(v)})")
                       for k, v in sorted(by.items(), key=lambda kv: kv[0] != "ok"))
    frames = [e["frame"] for e in plan["frames"]]
    g = lambda v: ", ".join(f"{x:g}" for x in v)  # noqa: E731
    return (f"{plan['pattern']}: {len(frames)} frames ({_ranges(frames)}): {counts}; grid "
            f"\"{plan['grid']}\"; union world bbox [{g(plan['bbox_min'])}] .. "
            f"[{g(plan['bbox_max'])}]; density scale {plan['scale']:.6g} ("
            + ("--scale" if plan.get("scale_rule") == "--scale" else
               "the median of the frames' default scales; change it with --scale") + ")")


def _ranges(frames):
    """[1, 2, 3, 7, 9, 10] -> '1-3, 7, 9-10'"""
    out, start, prev = [], None, None
    for f in sorted(frames) + [None]:
        if start is not None and (f is None or f != prev + 1):
            out.append(str(start) if start == prev else f"{start}-{prev}")
            start = None
        if f is not None and start is None:
            start = f
        prev = f
    return ", ".join(out)


# A frame's scene, the same on every shard

def frame_scene(mi, plan, volume_file, res, spp, integrator, filter_type):
    """(scene dict, info) of a plan's frame: framed_scene with the plan's
    camera and scale; volume_file None (an empty frame): no box, the lights"""
    return framed_scene(mi, volume_file, grid=plan["grid"], sequence=plan, res=res, spp=spp,
                        integrator=integrator, filter_type=filter_type)


def scene_json(scene, entry, grid):
    """A scene dict as JSON text (sorted keys): transforms as their
    matrices, the volume as the frame's file and grid (not the temporary
    .nvdb it was converted into), so that shards compare byte for byte"""
    import numpy as np

    def plain(v):
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        if isinstance(v, (str, int, float, bool)) or v is None:
            return v
        if type(v).__name__.startswith("ScalarTransform4"):
            return {"matrix": np.array(v.matrix).tolist()}
        if type(v).__name__ == "Volume" or "Volume" in type(v).__name__:
            return {"type": "nanovdbvolume", "file": entry["file"], "grid": grid,
                    "use_grid_transform": True}
        return str(v)
    return json.dumps(plain(scene), sort_keys=True, indent=1) + "\n"


# Rendering

def output_pattern(output, pattern):
    """Pattern of the frames' PNGs: -o with '#'s or '%04d', else -o's name
    (default: the input's) with .#### before .png"""
    if output and _TOKEN.search(os.path.basename(output)):
        p = parse_pattern(output)
        return Pattern(p.prefix, max(p.width, 4), os.path.splitext(p.suffix)[0] + ".png")
    if output:
        stem = os.path.splitext(output)[0]
    else:
        stem = os.path.basename(pattern.prefix.rstrip("._-")) or "frame"
    return Pattern(stem + ".", max(pattern.width, 4), ".png")


def written(png):
    """A frame counts as done when both its PNG and EXR are there"""
    return os.path.exists(png) and os.path.exists(os.path.splitext(png)[0] + ".exr")


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
                    scene_json_dir=None, log=print):
    """Renders the frames of `spec` (see the module's doc). frames: a list
    of frame numbers (default: from the first to the last file found, or the
    plan's); shard (I, N); plan_path: read the plan there if it exists,
    else scan, write it there and return without rendering. Returns a dict:
    plan, rendered / skipped / missing / empty / failed frame lists, seconds."""
    import mitsuba as mi
    import drjit as dr
    import numpy as np
    mi.set_variant(variant)
    setup(mi)
    pattern = parse_pattern(spec)
    plan = None
    if plan_path and os.path.exists(plan_path):
        plan = read_plan(plan_path)
        if grid and grid != plan["grid"]:
            raise SystemExit(f"nanovdb-render: --grid \"{grid}\" but the plan \"{plan_path}\" "
                             f"renders grid \"{plan['grid']}\"")
        if scale is not None and scale != plan["scale"]:
            raise SystemExit(f"nanovdb-render: --scale {scale:g} but the plan \"{plan_path}\" "
                             f"has scale {plan['scale']:g}: write a new plan with --scale")
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
                    log=log)
        log(summary_line(plan))
        if plan_path:
            write_plan(plan, plan_path)
            log(f"wrote the plan {plan_path}; render with --plan {plan_path} "
                "[--shard I/N] (nothing rendered yet)")
            return dict(plan=plan, rendered=[], skipped=[], missing=[], empty=[], failed=[],
                        seconds=0.0)
    else:
        log(summary_line(plan))
    entries = [e for e in plan["frames"] if frames is None or e["frame"] in frames]
    if shard is not None:
        entries = shard_frames(entries, shard)
    outpat = output_pattern(output, pattern)
    if os.path.dirname(outpat.prefix):
        os.makedirs(os.path.dirname(outpat.prefix), exist_ok=True)
    result = dict(plan=plan, rendered=[], skipped=[], missing=[], empty=[], failed=[])
    todo = [e for e in entries if overwrite or not written(outpat.path(e["frame"]))]
    skipped = [e["frame"] for e in entries if e not in todo]
    result["skipped"] = skipped
    if skipped:
        log(f"{len(skipped)} frames already written ({_ranges(skipped)}): skipped"
            " (--overwrite renders them again)")
    started = time.perf_counter()
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, entry in enumerate(todo):
            f = entry["frame"]
            t0 = time.perf_counter()
            head = f"frame {f} [{i + 1}/{len(todo)}]"
            # The file as it is now, on this machine (the plan may be older)
            path = pattern.path(f)
            try:
                status, why, volume, nvdb = load_frame(mi, path, plan["grid"], tmp, filter_type)
            except FrameError as e:
                status, why, volume, nvdb = "error", str(e), None, None
            if status in ("missing", "error"):
                result["missing" if status == "missing" else "failed"].append(f)
                log(f"{head}: {path}: {why}: skipped, no image written")
                continue
            del volume
            scene, info = frame_scene(mi, plan, nvdb if status == "ok" else None, res, spp,
                                      integrator, filter_type)
            png = outpat.path(f)
            if scene_json_dir is not None:
                name = os.path.splitext(os.path.basename(png))[0] + ".scene.json"
                with open(os.path.join(scene_json_dir, name), "w") as fh:
                    fh.write(scene_json(scene, dict(entry, file=path), plan["grid"]))
            img = mi.render(mi.load_dict(scene), spp=spp, seed=f)
            dr.eval(img)
            write_frame(mi, np.array(img, dtype=np.float32), png)
            del scene, info, img
            if nvdb and nvdb != path:
                os.remove(nvdb)
            dt = time.perf_counter() - t0
            times.append(dt)
            left = len(todo) - i - 1
            eta = sum(times) / len(times) * left
            what = "" if status == "ok" else f" ({why}: the sky and the sun only)"
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
        "renders every frame (out.0001.png ...) with one camera and one density scale")
    g.add_argument("--frames", metavar="A-B[:S]", help="the frames to render: 10-120, 10-120:2, "
                   "7, 1-5,9 (default: from the first file to the last)")
    g.add_argument("--shard", metavar="I/N", help="render every N-th frame from the I-th (0-based), "
                   "e.g. $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT; needs --plan")
    g.add_argument("--plan", metavar="FILE", help="the sequence's summary (JSON: union box, "
                   "scale, frames): read if FILE exists, else scan, write FILE and stop")
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
    fire_used = [o for o in ("emission_mode", "temperature_scale", "temperature_offset",
                             "emission_scale") if getattr(a, o, None) is not None]
    if fire_used or getattr(a, "emission_grid", None) not in (None, "none"):
        ap.error("emission (--emission-*, --temperature-*) is not rendered in sequences yet: "
                 "render single frames for fire")
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
                        log=lambda s: print(s, flush=True))
    except RuntimeError as e:
        raise SystemExit(f"nanovdb-render: {str(e).rsplit('] ', 1)[-1].strip()}")
    return True


if __name__ == "__main__":
    sys.exit("run nanovdb-render (python -m nanovdb_mitsuba.render) with 'name.####.vdb'")
