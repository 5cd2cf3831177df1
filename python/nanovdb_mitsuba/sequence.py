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
import re
import statistics
import sys
import time

from nanovdb_mitsuba import files, fire, setup
from nanovdb_mitsuba.facts import volume_facts
from nanovdb_mitsuba.scene import default_scale, framed_scene

# 2: the fire ("emission", "albedo", the frames' "emission_max"); a version-1
# plan (no emission) is refused, to be written again
PLAN_VERSION = 2
SCALE_RULE = "median over the frames with voxels of each frame's default scale"
# The fire options (render.py's) as they reach render_sequence; a plan
# records those it was scanned with (its "emission_options")
EMISSION_OPTIONS = ("emission_grid", "emission_mode", "temperature_scale", "temperature_offset",
                    "emission_scale")

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


# The frames' files: listed and loaded as files.py reads them (nanovdbvolume
# on the file itself: no converter, no temporary file)

def list_grids(path):
    """[(name, type)] of a file's grids (files.grid_rows); FrameError with
    the message, which names the file, if it cannot be read"""
    try:
        return files.grid_rows(path)
    except files.FileError as e:
        raise FrameError(str(e))


def default_grid(rows):
    """The grid nanovdb-render renders of a file: fire.default_density's
    choice, else the first grid"""
    return fire.default_density(rows) or (rows[0][0] if rows else "")


def resolve(rows, name):
    """The grid of [(name, type)] called `name`, exactly or else
    case-insensitively (one match); None without one"""
    names = [n for n, _ in rows]
    if name in names:
        return name
    folded = [n for n in names if n.lower() == name.lower()]
    return folded[0] if len(folded) == 1 else None


def load_frame(mi, path, grid, filter_type="trilinear", emission=None, rows=None):
    """(status, why, volume, emission_name) of one frame: status "ok"
    (volume loaded from `path` itself, a level set made a fog volume),
    "empty" (no such grid, or no positive value) or "missing"; FrameError
    where the file cannot be read. emission: the sequence's emission grid;
    emission_name is its name in this file, None where the file lacks it.
    rows: the file's grids, if already listed."""
    if not os.path.exists(path):
        return "missing", "no such file", None, None
    rows = list_grids(path) if rows is None else rows
    if grid not in [n for n, _ in rows]:
        listed = ", ".join(f'"{n}"' for n, _ in rows) or "no grids"
        return "empty", f'no grid "{grid}" (the file holds {listed})', None, None
    ename = resolve(rows, emission) if emission else None
    try:
        volume = files.load_volume(mi, path, grid, filter_type)
    except files.FileError as e:
        raise FrameError(str(e))
    facts = volume_facts(volume)
    if not facts["max"] > 0.0:
        why = ("holds no active voxels" if facts["index_dims"] == [1, 1, 1]
               else "holds no positive density")
        return "empty", f'grid "{grid}" {why}', None, ename
    return "ok", "", volume, ename


# The plan: what every shard must agree on

def choose_emission(pattern, rows_by_frame, density, emission_grid=None, mode=None):
    """(name, mode, found, why) of a sequence's emission grid, from
    {frame: [(name, type)]}: the grid a single file would glow with
    (fire.choose: by name, or `emission_grid`), the one most frames would
    choose (ties: fire.EMISSION_NAMES's order), so that one grid and one
    mode serve every frame. found: the emission-like grids of any frame;
    name None and why a sentence without one."""
    def preference(n):
        low = n.lower()
        return fire.EMISSION_NAMES.index(low) if low in fire.EMISSION_NAMES else len(
            fire.EMISSION_NAMES)
    found = sorted({n for rows in rows_by_frame.values()
                    for n in fire.emission_candidates([r[0] for r in rows], exclude=density)},
                   key=lambda n: (preference(n), n))
    if emission_grid is not None and emission_grid.lower() == "none":
        return None, None, found, "--no-emission"
    if emission_grid:
        name = emission_grid
        if not any(resolve(rows, name) for rows in rows_by_frame.values()):
            held = sorted({n for rows in rows_by_frame.values() for n, _ in rows})
            listed = ", ".join(f'"{n}"' for n in held) or "no grids"
            raise SystemExit(f'nanovdb-render: {pattern.text}: no frame holds a grid "{name}" '
                             f"for --emission-grid; the frames hold: {listed}")
    else:
        votes = {}
        for rows in rows_by_frame.values():
            c = fire.emission_candidates([n for n, _ in rows], exclude=density)
            if c:
                votes[c[0]] = votes.get(c[0], 0) + 1
        if not votes:
            return None, None, found, "no grid named " + ", ".join(fire.EMISSION_NAMES)
        name = min(votes, key=lambda n: (-votes[n], preference(n), n))
    # Its mode and type from the first frame that holds it (fire.choose
    # checks them as for a single file)
    f, rows = next((f, rows) for f, rows in sorted(rows_by_frame.items()) if resolve(rows, name))
    held, mode = fire.choose(pattern.path(f), rows, density, resolve(rows, name), mode)
    return (held if not emission_grid else name), mode, found, ""


def emission_mapping(mi, plan, name, mode, entries, rows_by_frame, options):
    """plan["emission"]: one mapping for every frame, fire.emission_params
    given the largest emission max over the frames (None, and
    plan["emission_why"], where no frame can glow)"""
    glowing = [e for e in entries if e.get("emission_max") is not None]
    if not glowing:
        plan["emission_why"] = f'no frame with voxels holds a grid "{name}"'
        return None
    top = max(glowing, key=lambda e: e["emission_max"])
    vtype = next((dict(rows).get(resolve(rows, name)) for rows in rows_by_frame.values()
                  if resolve(rows, name)), "float")
    scales = {k: options.get(k) for k in ("temperature_scale", "temperature_offset",
                                          "emission_scale")}
    params, summary, why_not = fire.emission_params(
        mi, None, mode, top["emission_max"], channels=3 if vtype.startswith("vec3") else 1,
        **scales)
    if params is None:
        plan["emission_why"] = (f'grid "{name}" at its largest (frame {top["frame"]}): '
                                f"{why_not}")
        return None
    given = [f"--{k.replace('_', '-')}" for k, v in scales.items() if v is not None]
    if mode == "temperature":
        rule = (f"temperature_scale maps the largest max over the frames to "
                f"{fire.HOTTEST_KELVIN:g} K, emission_scale gives that temperature "
                f"luminance {fire.BRIGHTNESS:g}")
    else:
        rule = (f"emission_scale gives the largest max over the frames luminance "
                f"{fire.FLAME_BRIGHTNESS:g}")
    if given:
        rule += " (" + ", ".join(given) + " as given)"
    return dict(grid=name, mode=mode, max=top["emission_max"], max_frame=top["frame"],
                rule=rule, summary=summary,
                **{k: v for k, v in params.items() if isinstance(v, float)})


def scan(mi, pattern, frames, grid="", scale=None, filter_type="trilinear", log=print,
         **emission_options):
    """The plan of `frames` of `pattern` (a dict, see plan_json): every frame
    read once for its status, world box and default scale, and its emission
    grid's max. emission_options: render.py's fire options (EMISSION_OPTIONS;
    emission_grid "none": no fire)"""
    options = {k: emission_options.get(k) for k in EMISSION_OPTIONS}
    unknown = set(emission_options) - set(EMISSION_OPTIONS)
    if unknown:
        raise TypeError(f"scan: unknown options {sorted(unknown)}")
    # The grids of every frame, once: the density and the emission grid
    # most frames would be rendered with alone
    rows_by_frame = {}
    for f in frames:
        path = pattern.path(f)
        if os.path.exists(path):
            try:
                rows_by_frame[f] = list_grids(path)
            except FrameError:
                continue
    if not grid:
        votes = {}
        for rows in rows_by_frame.values():
            name = default_grid(rows)
            if name:
                votes[name] = votes.get(name, 0) + 1
        grid = max(votes, key=votes.get) if votes else "density"
    ename, mode, found, no_emission = choose_emission(
        pattern, rows_by_frame, grid, options["emission_grid"], options["emission_mode"])
    entries = []
    started = time.perf_counter()
    for i, f in enumerate(frames):
        entry = {"frame": f, "file": pattern.path(f)}
        try:
            status, why, volume, held = load_frame(mi, entry["file"], grid, filter_type,
                                                   emission=ename, rows=rows_by_frame.get(f))
        except FrameError as e:
            status, why, volume, held = "error", str(e), None, None
        entry["status"] = status
        if why:
            entry["why"] = why
        if volume is not None:
            bb = volume.bbox()
            entry["bbox_min"] = [float(x) for x in bb.min]
            entry["bbox_max"] = [float(x) for x in bb.max]
            entry["scale"] = float(default_scale(volume))
            if ename and not held:
                entry["emission_why"] = f'no grid "{ename}"'
            elif held:
                # The emission grid's max (an upper bound of its lookups)
                try:
                    ev = volume if held == grid else files.load_volume(mi, entry["file"], held,
                                                                       filter_type)
                    entry["emission_max"] = float(volume_facts(ev)["max"])
                    del ev
                except files.FileError as e:
                    entry["emission_why"] = str(e)
            del volume
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
        # A fire's smoke: fire.FIRE_ALBEDO wherever a frame holds an
        # emission grid, rendered or not (as for a single file)
        "albedo": fire.FIRE_ALBEDO if (ename or found) else 0.9,
        "emission_found": found,
        "emission_options": {k: v for k, v in options.items() if v is not None},
    }
    plan["emission"] = emission_mapping(mi, plan, ename, mode, ok, rows_by_frame,
                                        options) if ename else None
    if not ename:
        plan["emission_why"] = no_emission
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
                           "bbox_max", "scale", "albedo", "emission") if k not in plan]
    if missing or plan.get("nanovdb_sequence") != PLAN_VERSION:
        raise SystemExit(f"nanovdb-render: plan \"{path}\": not a version-{PLAN_VERSION} "
                         f"sequence plan (missing: {', '.join(missing) or 'none'}); write it "
                         "again: the same command with --plan and a new FILE")
    return plan


def emission_line(plan, rendered=True):
    """The fire of a plan in one line: the mapping every frame shares"""
    em = plan.get("emission")
    head = f"{plan['pattern']}: "
    if not rendered and em:
        return head + f'emission grid "{em["grid"]}": not rendered (--no-emission)'
    if not em:
        why = plan.get("emission_why", "")
        found = plan.get("emission_found") or []
        listed = (" (emission grids " + ", ".join(f'"{n}"' for n in found) + ")") if found else ""
        return head + f"no emission: {why}{listed}"
    with_grid = [e for e in plan["frames"] if e.get("emission_max") is not None]
    ok = [e for e in plan["frames"] if e["status"] == "ok"]
    return (head + f'emission grid "{em["grid"]}" in {len(with_grid)} of {len(ok)} frames with '
            f"voxels; one mapping for all frames, from the largest max (frame "
            f"{em['max_frame']}): {em['summary']}; albedo {plan['albedo']:g}")


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
