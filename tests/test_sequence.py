"""nanovdb-render on a sequence of frames (python/nanovdb_mitsuba/sequence.py):
a generated cloud that drifts and grows over 8 frames (`vdb2nvdb generate
drifting_cloud_<F>`: every frame its own box and transform), frame 4 empty
(a "density" grid without voxels), frame 6 missing. One camera fitted to
the union of the frames' boxes, one density scale, frames written one by
one and skipped on a re-run, --frames and --shard partitioning the frames,
shards given one plan building byte-identical scenes, and the empty and
missing frames reported in one line each without stopping the run. Then
fire (test08-11): one emission mapping in the plan, shards agreeing on the
emissive scene, frames without the emission grid rendered without it."""
import json
import os
import re
import statistics
import subprocess
import sys

import pytest

from conftest import BUILD, ROOT

sys.path.insert(0, str(ROOT / "python"))
from nanovdb_mitsuba import frames as seq_frames, plan as seq_plan  # noqa: E402
from nanovdb_mitsuba.scene import _project, framed_scene  # noqa: E402

FRAMES = list(range(1, 9))
EMPTY, MISSING = 4, 6
RES, SPP = 16, 2
ENV = dict(os.environ, PYTHONPATH=str(ROOT / "python"))


@pytest.fixture(scope="module")
def frames_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("seq")
    exe = str(BUILD / "bin" / "vdb2nvdb")
    for f in FRAMES:
        if f == MISSING:
            continue
        case = "empty" if f == EMPTY else f"drifting_cloud_{f}"
        subprocess.run([exe, "generate", case, str(d / f"smoke.{f:04d}.vdb")], check=True,
                       capture_output=True)
    return d


def command(*args, cwd):
    p = subprocess.run([sys.executable, "-m", "nanovdb_mitsuba.render", *map(str, args),
                        "--res", str(RES), "--spp", str(SPP)], env=ENV, cwd=cwd,
                       capture_output=True, text=True)
    assert "Traceback" not in p.stderr, p.stderr
    return p


def wrote(stdout):
    """The frames a run rendered, from its progress lines"""
    return [int(m.group(1)) for m in re.finditer(r"^frame (\d+) \[\d+/\d+\]: wrote", stdout,
                                                   re.M)]


@pytest.fixture(scope="module")
def plan(frames_dir):
    p = command(frames_dir / "smoke.####.vdb", "--plan", "plan.json", cwd=frames_dir)
    assert p.returncode == 0, p.stderr
    assert "wrote the plan plan.json" in p.stdout
    return json.loads((frames_dir / "plan.json").read_text())


def test01_patterns_frames_and_shards():
    for spec in ("a/smoke.####.vdb", "a/smoke.%04d.vdb"):
        p = seq_frames.parse_pattern(spec)
        assert p.path(12) == "a/smoke.0012.vdb" and p.text == "a/smoke.####.vdb"
    assert seq_frames.parse_pattern("smoke.%d.nvdb").path(7) == "smoke.7.nvdb"
    assert seq_frames.parse_frames("10-20:5,3") == [3, 10, 15, 20]
    assert seq_frames.parse_frames("10-120:2") == list(range(10, 121, 2))
    for bad in ("5-2", "1-3:0", "x", "1/2"):
        with pytest.raises(ValueError):
            seq_frames.parse_frames(bad)
    frames = seq_frames.parse_frames("10-120:2")
    for n in (1, 2, 3, 7, 56, 60):
        shards = [seq_frames.shard_frames(frames, seq_frames.parse_shard(f"{i}/{n}")) for i in range(n)]
        flat = [f for s in shards for f in s]
        assert sorted(flat) == frames and len(flat) == len(set(flat))  # each frame once
    for bad in ("3/3", "-1/2", "1", "a/b"):
        with pytest.raises(ValueError):
            seq_frames.parse_shard(bad)


def test02_folder_input_finds_the_frames(frames_dir):
    p = seq_frames.parse_pattern(str(frames_dir))
    assert p.text == str(frames_dir / "smoke.####.vdb")
    assert sorted(p.found()) == [f for f in FRAMES if f != MISSING]


def test03_plan_summarises_the_sequence(plan, frames_dir):
    status = {e["frame"]: e["status"] for e in plan["frames"]}
    assert status == {f: "empty" if f == EMPTY else "missing" if f == MISSING else "ok"
                      for f in FRAMES}
    ok = [e for e in plan["frames"] if e["status"] == "ok"]
    # The frames differ in box (the cloud drifts and grows)
    assert len({tuple(e["bbox_min"] + e["bbox_max"]) for e in ok}) == len(ok)
    for e in ok:
        assert all(plan["bbox_min"][k] <= e["bbox_min"][k] and
                   e["bbox_max"][k] <= plan["bbox_max"][k] for k in range(3))
    for k in range(3):  # the union, not more
        assert plan["bbox_min"][k] == min(e["bbox_min"][k] for e in ok)
        assert plan["bbox_max"][k] == max(e["bbox_max"][k] for e in ok)
    # One scale: the median of the frames' own default scales
    assert plan["scale"] == statistics.median(e["scale"] for e in ok)
    assert len({e["scale"] for e in ok}) > 1
    assert plan["grid"] == "density"
    assert not list(frames_dir.glob("*.png"))  # the first pass renders nothing


def test04_one_camera_frames_every_frame(plan, frames_dir, tmp_path):
    """framed_scene with the plan (the Python route): one camera and one
    scale for all frames; the union box's corners, and so every frame's box,
    project inside the image"""
    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    import nanovdb_mitsuba  # noqa: F401  (the plugins)
    cams, scales = set(), set()
    for e in plan["frames"]:
        if e["status"] != "ok":
            continue
        # The frame's .vdb itself, as the command reads it
        nvdb = str(frames_dir / f"smoke.{e['frame']:04d}.vdb")
        scene, info = framed_scene(mi, nvdb, sequence=plan, res=RES)
        cam = info["camera"]
        cams.add(json.dumps(cam, sort_keys=True))
        scales.add(scene["box"]["interior"]["scale"])
        assert info["bbox_min"] == e["bbox_min"] and info["bbox_max"] == e["bbox_max"]
        for lo, hi in ((plan["bbox_min"], plan["bbox_max"]), (e["bbox_min"], e["bbox_max"])):
            for i in range(8):
                q = _project([hi[k] if (i >> k) & 1 else lo[k] for k in range(3)],
                             cam["origin"], cam["target"], cam["fov"])
                assert q is not None and abs(q[0]) <= 1 and abs(q[1]) <= 1
        # Without a summary: the frame's own camera and scale, as before
        alone, ainfo = framed_scene(mi, nvdb, res=RES)
        assert ainfo["scale"] == e["scale"] and ainfo["camera"] != cam
        del scene, info, alone, ainfo
    assert len(cams) == 1 and scales == {plan["scale"]}
    # An empty frame (filename None): the same camera and lights, no box
    scene, info = framed_scene(mi, None, sequence=plan, res=RES)
    assert "box" not in scene and json.dumps(info["camera"], sort_keys=True) in cams


def test05_render_rerun_and_overwrite(frames_dir, tmp_path):
    out = tmp_path / "out"
    p = command(frames_dir / "smoke.%04d.vdb", "-o", out / "cloud.png", "--scene-json",
                tmp_path / "scenes", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    rendered = [f for f in FRAMES if f != MISSING]
    assert wrote(p.stdout) == rendered
    for f in rendered:
        assert (out / f"cloud.{f:04d}.png").exists() and (out / f"cloud.{f:04d}.exr").exists()
    assert not (out / f"cloud.{MISSING:04d}.png").exists()
    # The empty and the missing frame: one line each, and the run went on
    lines = p.stdout.splitlines()
    assert len([ln for ln in lines if ln.startswith(f"frame {EMPTY} ")
                and "holds no active voxels" in ln]) == 1
    assert len([ln for ln in lines if ln.startswith(f"frame {MISSING} ")
                and "no such file" in ln]) == 1
    assert re.search(r"; \d+ to go, about \d+ s left$", p.stdout, re.M)  # the estimate
    # Every frame's scene: the same sensor and scale
    scenes = [json.loads((tmp_path / "scenes" / f"cloud.{f:04d}.scene.json").read_text())
              for f in rendered]
    assert len({json.dumps(s["sensor"], sort_keys=True) for s in scenes}) == 1
    assert len({s["box"]["interior"]["scale"] for s in scenes if "box" in s}) == 1
    assert sum("box" not in s for s in scenes) == 1  # the empty frame
    # A re-run skips every written frame
    mtimes = {f: os.stat(out / f"cloud.{f:04d}.png").st_mtime_ns for f in rendered}
    p = command(frames_dir / "smoke.%04d.vdb", "-o", out / "cloud.png", cwd=tmp_path)
    assert p.returncode == 0 and wrote(p.stdout) == [], p.stdout
    assert f"{len(rendered)} frames already written" in p.stdout
    # --overwrite redoes them (here the frames 2-3 picked by --frames)
    p = command(frames_dir / "smoke.%04d.vdb", "-o", out / "cloud.png", "--frames", "2-3",
                "--overwrite", cwd=tmp_path)
    assert p.returncode == 0 and wrote(p.stdout) == [2, 3], p.stdout
    for f in rendered:
        changed = os.stat(out / f"cloud.{f:04d}.png").st_mtime_ns != mtimes[f]
        assert changed == (f in (2, 3)), f


def test06_shards_partition_and_agree(plan, frames_dir, tmp_path):
    """Three shards with one plan render every frame once; shards 0/3 and
    0/2 (both render frames 1 and 7) build byte-identical scenes for them"""
    plan_file = frames_dir / "plan.json"
    done = []
    for i in range(3):
        p = command(frames_dir / "smoke.####.vdb", "-o", tmp_path / "out" / "s.png", "--plan",
                    plan_file, "--shard", f"{i}/3", "--scene-json", tmp_path / "a", cwd=tmp_path)
        assert p.returncode == 0, p.stderr
        assert "scanning" not in p.stdout  # the plan, not a scan
        done += wrote(p.stdout) + [int(m) for m in re.findall(r"^frame (\d+) .*no such file",
                                                              p.stdout, re.M)]
    assert sorted(done) == FRAMES and len(done) == len(set(done))
    p = command(frames_dir / "smoke.####.vdb", "-o", tmp_path / "out2" / "s.png", "--plan",
                plan_file, "--shard", "0/2", "--scene-json", tmp_path / "b", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert wrote(p.stdout) == [1, 3, 5, 7]
    for f in (1, 7):
        a = (tmp_path / "a" / f"s.{f:04d}.scene.json").read_bytes()
        b = (tmp_path / "b" / f"s.{f:04d}.scene.json").read_bytes()
        assert a == b
        assert json.loads(a)["box"]["interior"]["scale"] == plan["scale"]


def test07_command_line_errors(frames_dir, tmp_path):
    p = command(frames_dir / "smoke.####.vdb", "--shard", "0/2", "--plan", tmp_path / "no.json",
                cwd=tmp_path)
    assert p.returncode != 0 and "--shard needs an existing plan" in p.stderr
    p = command(frames_dir / "smoke.0001.vdb", "--frames", "1-3", cwd=tmp_path)
    assert p.returncode != 0 and "for sequences" in p.stderr
    p = command(frames_dir / "smoke.####.vdb", "--shard", "2/2", cwd=tmp_path)
    assert p.returncode != 0 and "--shard" in p.stderr
    p = command(tmp_path / "none.####.vdb", cwd=tmp_path)
    assert p.returncode != 0 and "no files match" in p.stderr


# Fire: a generated sequence with emission. The generator has no fire case
# whose glow overlaps its smoke ("multi"'s temperature lies outside its
# density's box), so frames 1-3 are the drifting cloud read as its own
# temperature (--emission-grid density --emission-mode temperature: plan
# "a") and frame 4 is "multi"; by name (plan "b") only frame 4 holds a
# "temperature", so frames 1-3 render without emission.

@pytest.fixture(scope="module")
def fire_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("fire")
    exe = str(BUILD / "bin" / "vdb2nvdb")
    for f in (1, 2, 3, 4):
        case = "multi" if f == 4 else f"drifting_cloud_{f}"
        subprocess.run([exe, "generate", case, str(d / f"fire.{f:04d}.vdb")], check=True,
                       capture_output=True)
    runs = {}
    for name, opts in (("a", ["--emission-grid", "density", "--emission-mode", "temperature"]),
                       ("b", [])):
        p = command(d / "fire.####.vdb", "--plan", f"{name}.json", *opts, cwd=d)
        assert p.returncode == 0, p.stderr
        runs[name] = (json.loads((d / f"{name}.json").read_text()), p.stdout)
    return d, runs


def exr_mean(path):
    import mitsuba as mi
    import numpy as np
    mi.set_variant("llvm_ad_rgb")
    return float(np.array(mi.Bitmap(str(path))).mean())


def test08_fire_plan_holds_one_mapping(fire_dir):
    import mitsuba as mi
    from nanovdb_mitsuba import fire
    mi.set_variant("llvm_ad_rgb")
    d, runs = fire_dir
    for name, grid, with_grid in (("a", "density", [1, 2, 3, 4]), ("b", "temperature", [4])):
        plan, out = runs[name]
        em = plan["emission"]
        assert em["grid"] == grid and em["mode"] == "temperature"
        assert plan["albedo"] == fire.FIRE_ALBEDO
        frames = {e["frame"]: e for e in plan["frames"]}
        assert [f for f, e in frames.items() if "emission_max" in e] == with_grid
        # One mapping: the largest max over the frames -> HOTTEST_KELVIN
        top = max(frames[f]["emission_max"] for f in with_grid)
        assert em["max"] == top and frames[em["max_frame"]]["emission_max"] == top
        assert em["temperature_scale"] == pytest.approx(fire.HOTTEST_KELVIN / top, rel=1e-12)
        want, _, _ = fire.emission_params(mi, None, "temperature", top)
        assert {k: em[k] for k in want} == want
        # printed once
        assert len([ln for ln in out.splitlines() if "one mapping for all frames" in ln]) == 1
    assert all(runs["b"][0]["frames"][f - 1]["emission_why"] == 'no grid "temperature"'
               for f in (1, 2, 3))
    # The rule on frames of different maxima: the hottest frame decides
    plan = {}
    em = seq_plan.emission_mapping(
        mi, plan, "heat", "temperature",
        [{"frame": 1, "emission_max": 0.5}, {"frame": 2, "emission_max": 2.0}, {"frame": 3}],
        {1: [("heat", "float")]}, {})
    assert em["max_frame"] == 2 and em["temperature_scale"] == fire.HOTTEST_KELVIN / 2.0
    em = seq_plan.emission_mapping(mi, plan, "flame", "radiance",
                              [{"frame": 1, "emission_max": 0.5},
                               {"frame": 2, "emission_max": 4.0}],
                              {1: [("flame", "float")]}, {})
    assert em["emission_scale"] == fire.FLAME_BRIGHTNESS / 4.0 and "temperature_scale" not in em


def test09_fire_shards_agree_and_glow(fire_dir, tmp_path):
    """Two shards with plan "a" build byte-identical emissive scenes for
    frame 2; the frame is brighter than with --no-emission"""
    d, runs = fire_dir
    plan = runs["a"][0]
    for i, opts in enumerate((["--frames", "1-3", "--shard", "1/2"], ["--frames", "2"],
                              ["--frames", "2", "--no-emission"])):
        p = command(d / "fire.####.vdb", "-o", tmp_path / f"o{i}" / "f.png", "--plan", d / "a.json",
                    "--scene-json", tmp_path / f"s{i}", *opts, cwd=tmp_path)
        assert p.returncode == 0, p.stderr
        assert wrote(p.stdout) == [2] and "scanning" not in p.stdout
        assert "without emission" not in p.stdout
    a, b, c = [(tmp_path / f"s{i}" / "f.0002.scene.json").read_bytes() for i in range(3)]
    assert a == b
    medium = json.loads(a)["box"]["interior"]
    assert medium["type"] == "emissiveheterogeneous"
    assert medium["temperature"]["grid"] == "density"
    for k in ("temperature_scale", "temperature_offset", "temperature_cutoff", "emission_scale"):
        assert medium[k] == plan["emission"][k]
    plain = json.loads(c)["box"]["interior"]
    assert plain["type"] == "heterogeneous" and plain["albedo"] == medium["albedo"]
    glow, smoke = (exr_mean(tmp_path / f"o{i}" / "f.0002.exr") for i in (1, 2))
    assert glow > 1.05 * smoke, (glow, smoke)


def test10_fire_frames_without_the_grid(fire_dir, tmp_path):
    """Plan "b": frame 1 has no "temperature": one line, no emission, the
    run goes on; frame 4's scene glows (framed_scene with the plan, the
    Python route); an empty emission grid renders without emission too"""
    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    d, runs = fire_dir
    plan = runs["b"][0]
    p = command(d / "fire.####.vdb", "-o", tmp_path / "o" / "f.png", "--plan", d / "b.json",
                "--frames", "1", "--scene-json", tmp_path / "s", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert wrote(p.stdout) == [1]
    assert len([ln for ln in p.stdout.splitlines() if ln.startswith("frame 1 ")
                and 'without emission: no grid "temperature"' in ln]) == 1
    medium = json.loads((tmp_path / "s" / "f.0001.scene.json").read_text())["box"]["interior"]
    assert medium["type"] == "heterogeneous" and medium["albedo"]["value"][0] == plan["albedo"]
    nvdb = str(d / "fire.0004.vdb")  # (the .vdb itself, as the command reads it)
    scene, info = framed_scene(mi, nvdb, sequence=plan, res=RES)
    assert scene["box"]["interior"]["type"] == "emissiveheterogeneous"
    assert info["emission"]["temperature_scale"] == plan["emission"]["temperature_scale"]
    # The frame's hottest value below the cutoff with the plan's scale: none
    cold = dict(plan, emission=dict(plan["emission"], temperature_scale=0.2))
    scene, info = framed_scene(mi, nvdb, sequence=cold, res=RES)
    assert info["emission"] is None and "cutoff" in info["emission_why_not"]
    assert scene["box"]["interior"]["type"] == "heterogeneous"
    del scene, info


def test11_fire_command_line_errors(fire_dir, tmp_path):
    d, runs = fire_dir
    p = command(d / "fire.####.vdb", "--plan", d / "a.json", "--emission-scale", "2",
                cwd=tmp_path)
    assert p.returncode != 0 and "--emission-scale 2.0 but the plan" in p.stderr
    p = command(d / "fire.####.vdb", "--plan", d / "a.json", "--integrator", "volpath",
                cwd=tmp_path)
    assert p.returncode != 0 and "only the volpathlocal integrator" in p.stderr
    p = command(d / "fire.####.vdb", "--emission-grid", "nosuch", "--plan", tmp_path / "c.json",
                cwd=tmp_path)
    assert p.returncode != 0 and 'no frame holds a grid "nosuch"' in p.stderr


def test12_each_frame_read_once(frames_dir, tmp_path):
    """The scan reads each frame's .vdb once: one listing and one read of
    its grid by nanovdbvolume's reader process (NVDB_VDB_READER_REPORT logs
    every request), no converter and no temporary .nvdb"""
    report = tmp_path / "reader.jsonl"
    env = dict(ENV, NVDB_VDB_READER_REPORT=str(report))
    p = subprocess.run([sys.executable, "-m", "nanovdb_mitsuba.render",
                        str(frames_dir / "smoke.####.vdb"), "--plan", str(tmp_path / "p.json")],
                       env=env, cwd=tmp_path, capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    rows = [json.loads(line) for line in report.read_text().splitlines()]
    requests = {}
    for r in rows:
        requests.setdefault(os.path.basename(r["file"]), []).append(r["request"])
    want = {f"smoke.{f:04d}.vdb": ["list", "grid"] for f in FRAMES if f != MISSING}
    assert requests == want
    assert not list(frames_dir.glob("*.nvdb")) and not list(tmp_path.glob("*.nvdb"))
