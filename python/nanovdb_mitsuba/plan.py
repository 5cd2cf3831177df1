"""A sequence's plan (sequence.py): the scan of every frame that fixes one
camera, one density scale and one fire mapping for all of them, and the
small JSON file a render farm's shards share (plan_json, --plan). Frames
are read as files.py reads a file (nanovdbvolume on the file itself)."""
import json
import os
import statistics
import time

from nanovdb_mitsuba import files, fire
from nanovdb_mitsuba.facts import volume_facts
from nanovdb_mitsuba.frames import FrameError, _ranges
from nanovdb_mitsuba.scene import default_scale

# 2: the fire ("emission", "albedo", the frames' "emission_max"); a version-1
# plan (no emission) is refused, to be written again
PLAN_VERSION = 2
SCALE_RULE = "median over the frames with voxels of each frame's default scale"
# The fire options (render.py's) as they reach render_sequence; a plan
# records those it was scanned with (its "emission_options")
EMISSION_OPTIONS = ("emission_grid", "emission_mode", "temperature_scale", "temperature_offset",
                    "emission_scale")

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
            f"{em['max_frame']}): {em['summary']}; albedo {plan['albedo']:g}; {fire.LIGHTING}")


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
