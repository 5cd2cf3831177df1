"""Benchmark cases: generated grids (cached in bench/data/) and user files.

Every case ends up as a `.nvdb` for `nanovdbvolume` and an aligned dense
`.vol` of the same active box for `gridvolume` (so the two plugins render the
same image under the same `to_world`).
"""
import hashlib
import os
import struct
import subprocess
import sys

import numpy as np

import harness  # (bench/: the dense export runs in a worker process)

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

# name -> (vdb2nvdb generate CASE, description)
GENERATED = {
    "constant_300": ("constant_300", "constant 5.0 in a 300^3 cube of active voxels"),
    "random_300": ("random_300", "uniform random values in [4.5, 5.5], 300^3"),
    "sphere_fog": ("sphere_ls", "sphere level set (radius 1, voxel 0.02) -> fog volume "
                                "(vdb2nvdb's default conversion)"),
    "cloud": ("cloud", "noisy cloud (fog, 0..1), 160^3 index box"),
    "sphere_fog_256": ("sphere_ls_256", "sphere level set of radius 256 voxels -> fog volume "
                                        "(interior tiles), 512^3 box: a large sparse volume"),
    "cloudfield_400": ("cloudfield_400", "sparse field of 24 noisy cloud puffs in a 400^3 "
                                         "box (1-2 % occupied), like production clouds"),
    "constant_934": ("constant_934", "constant 5.0 in a 934^3 cube (3.3 GB dense)"),
    "random_934": ("random_934", "uniform random values in [4.5, 5.5], 934^3"),
}
DEFAULT_CASES = ["constant_300", "random_300", "sphere_fog", "cloud", "sphere_fog_256",
                 "cloudfield_400"]
FULL_CASES = DEFAULT_CASES + ["constant_934", "random_934"]
# On a GPU: the sparse and the dense extremes, the small cloud (fixed costs)
GPU_CASES = ["constant_300", "cloud", "sphere_fog_256", "cloudfield_400"]


class Case:
    def __init__(self, name, nvdb, vol, grid="", source="generated", description=""):
        self.name, self.nvdb, self.vol, self.grid = name, nvdb, vol, grid
        self.source, self.description = source, description
        self.grid_bytes, self.grid_name = nvdb_grid_bytes(nvdb, grid)
        self.nvdb_file_bytes = os.path.getsize(nvdb)
        self.dense_res = vol_resolution(vol)
        self.dense_bytes = int(np.prod(self.dense_res)) * 4
        self.border_background = dense_border_is_zero(vol)

    def row(self):
        return {"case": self.name, "source": self.source, "grid": self.grid_name,
                "grid_arg": self.grid,
                "nvdb": os.path.relpath(self.nvdb, ROOT), "vol": os.path.relpath(self.vol, ROOT),
                "grid_bytes": self.grid_bytes, "nvdb_file_bytes": self.nvdb_file_bytes,
                "dense_res": "x".join(map(str, self.dense_res)), "dense_bytes": self.dense_bytes,
                "border_zero": self.border_background, "description": self.description}


class CaseRecord:
    """A Case rebuilt from its saved row (bench/run.py --report-only)."""

    def __init__(self, row):
        self._row = dict(row)
        self.name, self.source, self.grid_name = row["case"], row["source"], row["grid"]
        self.grid = row.get("grid_arg", "")
        self.nvdb, self.vol = os.path.join(ROOT, row["nvdb"]), os.path.join(ROOT, row["vol"])
        self.grid_bytes, self.nvdb_file_bytes = row["grid_bytes"], row["nvdb_file_bytes"]
        self.dense_res = [int(x) for x in str(row["dense_res"]).split("x")]
        self.dense_bytes, self.border_background = row["dense_bytes"], row["border_zero"]
        self.description = row["description"]

    def row(self):
        return dict(self._row)


def nvdb_grid_bytes(path, grid=""):
    """(grid size in bytes, grid name) of the selected grid of a .nvdb: the
    `gridSize` of its metadata record (segment files) or of its GridData (raw
    grid buffers). With no name: the first float grid, as the plugin picks."""
    with open(path, "rb") as f:
        data = f.read(16)
        if data[:7] != b"NanoVDB":
            raise ValueError(f"{path}: not a NanoVDB file")
        version, count, codec = struct.unpack_from("<IHH", data, 8)
        if version >> 21 != 32 or count == 0 or codec > 2:
            f.seek(32)  # raw grid buffer: GridData.mGridSize at byte 32
            return struct.unpack("<Q", f.read(8))[0], grid
        f.seek(0)
        first = None
        index = 0
        while True:
            seg = f.read(16)
            if len(seg) < 16 or seg[:7] != b"NanoVDB":
                break
            count = struct.unpack_from("<H", seg, 12)[0]
            metas = []
            for _ in range(count):
                rec = f.read(176)
                if len(rec) < 176:
                    raise ValueError(f"{path}: truncated metadata")
                gsize, fsize = struct.unpack_from("<QQ", rec, 0)
                gtype = struct.unpack_from("<I", rec, 32)[0]
                nsize = struct.unpack_from("<I", rec, 136)[0]
                metas.append((gsize, fsize, gtype, nsize))
            names = [f.read(m[3]).rstrip(b"\0").decode(errors="replace") for m in metas]
            for (gsize, _, gtype, _), name in zip(metas, names):
                if grid and (name == grid or grid == str(index)):
                    return gsize, name
                if not grid and first is None and gtype == 1:  # GridType::Float
                    first = (gsize, name)
                index += 1
            if first is not None:
                return first
            f.seek(sum(m[1] for m in metas), 1)
    raise ValueError(f"{path}: grid {grid!r} not found")


def vol_resolution(path):
    with open(path, "rb") as f:
        h = f.read(24)
    if h[:3] != b"VOL":
        raise ValueError(f"{path}: not a Mitsuba .vol file")
    return list(struct.unpack_from("<iii", h, 8))


def dense_border_is_zero(path):
    """True when every voxel on the faces of the dense box is 0 (the fog
    background): then the plugins' trilinear conventions at the border
    (nanovdbvolume blends towards the background, gridvolume clamps) agree."""
    X, Y, Z = vol_resolution(path)
    a = np.memmap(path, dtype=np.float32, mode="r", offset=48, shape=(Z, Y, X))
    faces = [a[0], a[-1], a[:, 0, :], a[:, -1, :], a[:, :, 0], a[:, :, -1]]
    return bool(all(np.all(np.asarray(fc) == 0) for fc in faces))


def vdb2nvdb(build):
    return os.path.join(build, "bin", "vdb2nvdb")


def _run(cmd, log):
    print("  $ " + " ".join(cmd), file=log, flush=True)
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({r.returncode}):\n{r.stdout}")
    return r.stdout


def generate(gen, base, build, dense=True, log=sys.stdout):
    """`vdb2nvdb generate GEN` into BASE.vdb and BASE.nvdb (and the dense
    BASE.vol of its first grid), cached: made again when the command
    changes. Returns BASE.nvdb."""
    data_dir = os.path.dirname(base)
    nvdb, vol, vdb, stamp = base + ".nvdb", base + ".vol", base + ".vdb", base + ".stamp"
    cmd = [vdb2nvdb(build), "generate", gen, vdb, nvdb] + (["--dense", vol] if dense else [])
    cmd.append("--stats")
    key = " ".join([gen] + cmd[3:]).replace(data_dir, "")
    if not (os.path.exists(nvdb) and (not dense or os.path.exists(vol))
            and os.path.exists(stamp) and open(stamp).read() == key):
        os.makedirs(data_dir, exist_ok=True)
        out = _run(cmd, log)
        with open(base + ".stats.txt", "w") as f:
            f.write(out)
        with open(stamp, "w") as f:
            f.write(key)
    return nvdb


def generated_case(name, data_dir, build, log=sys.stdout):
    gen, desc = GENERATED[name]
    base = os.path.join(data_dir, name)
    nvdb = generate(gen, base, build, log=log)
    return Case(name, nvdb, base + ".vol", "", "generated", desc)


def _user_base(path, grid, data_dir):
    st = os.stat(path)
    h = hashlib.sha1(f"{os.path.abspath(path)}|{st.st_size}|{st.st_mtime_ns}|{grid}".encode())
    stem = os.path.splitext(os.path.basename(path))[0]
    return os.path.join(data_dir, "user", f"{stem}{'_' + grid if grid else ''}-{h.hexdigest()[:8]}")


def split_grid(arg):
    """FILE or FILE:GRID."""
    if ":" in arg and not os.path.exists(arg):
        f, g = arg.rsplit(":", 1)
        return f, g
    return arg, ""


def first_float_grid(vdb, build):
    """The first float grid of a file, from the listing of `build`'s grid
    library (nanovdb_mitsuba.files: structured, not vdb2nvdb --list's text)"""
    os.environ["NVDB_BUILD_DIR"] = os.path.abspath(build)  # (the library read; also the children's)
    if os.path.join(ROOT, "python") not in sys.path:
        sys.path.insert(0, os.path.join(ROOT, "python"))
    from nanovdb_mitsuba import files
    rows = files.grid_rows(vdb)
    for name, type_ in rows:
        if type_ == "float":
            return name
    raise RuntimeError(f"{vdb}: no float grid (its grids: {rows})")


def vdb_case(arg, data_dir, build, log=sys.stdout):
    path, grid = split_grid(arg)
    grid = grid or first_float_grid(path, build)
    base = _user_base(path, grid, data_dir)
    nvdb, vol = base + ".nvdb", base + ".vol"
    if not (os.path.exists(nvdb) and os.path.exists(vol)):
        os.makedirs(os.path.dirname(base), exist_ok=True)
        out = _run([vdb2nvdb(build), "--grid", grid, path, nvdb, "--dense", vol, "--stats"], log)
        with open(base + ".stats.txt", "w") as f:
            f.write(out)
    name = os.path.splitext(os.path.basename(path))[0] + (f":{grid}" if grid else "")
    return Case(name, nvdb, vol, "", "vdb", f"{path} (converted by vdb2nvdb, level sets -> fog)")


def nvdb_case(arg, data_dir, build, max_dense_bytes, log=sys.stdout):
    """A user .nvdb: the dense baseline is read back through nanovdbvolume
    (nearest, every voxel centre) in a worker process."""
    path, grid = split_grid(arg)
    path = os.path.abspath(path)
    base = _user_base(path, grid, data_dir)
    vol = base + ".vol"
    if not os.path.exists(vol):
        os.makedirs(os.path.dirname(base), exist_ok=True)
        spec = {"mode": "dense", "variant": "llvm_ad_rgb", "build": build, "volume": path,
                "grid": grid, "dense_out": vol, "max_dense_bytes": max_dense_bytes}
        print(f"  dense export of {path} (nanovdbvolume, nearest)", file=log, flush=True)
        try:
            harness.run_child("worker:measure", spec, echo=True)
        except harness.ChildFailed as e:
            raise RuntimeError(f"dense export of {path} failed") from e
    name = os.path.splitext(os.path.basename(path))[0] + (f":{grid}" if grid else "")
    return Case(name, path, vol, grid, "nvdb", f"{path} (as given)")
