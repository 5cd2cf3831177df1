"""A volume file's grids and its volume: the one way nanovdb-render and its
sequences read a .nvdb or .vdb file.

    rows = grid_rows("smoke.vdb")          # [("density", "float"), ("heat", "float")]
    volume = load_volume(mi, "smoke.vdb", "density")

list_grids() asks lib/nanovdb_grid_list.so (src/python/grid_list.cpp) for
the file's grids as records: the loader's headers for a .nvdb (no payload
read), the .vdb reader process's listing for a .vdb (no voxels read; a
damaged file is an error, never a crash of this process). load_volume()
hands the file itself to nanovdbvolume, which reads only the grid asked for
(a .vdb through the same reader process) and makes a level set a fog volume
with level_set="fog", for .nvdb files too. No converter runs and no
temporary file is written. Errors are FileError, whose message names the
file and the problem.
"""
import ctypes
import functools
import json
import os
from collections import namedtuple

from . import plugin_root

# type: the value type as OpenVDB and vdb2nvdb name it: "float" for any
# one-channel float grid nanovdbvolume reads (float, Half, Fp4, Fp8, Fp16,
# FpN), "vec3s" for Vec3f, else the file's own name ("int32", "OnIndex",
# "ptdataidx32", ...); stored_type: the file's own name; grid_class:
# "level set", "fog volume", "unknown", ...
GridInfo = namedtuple("GridInfo", "index name type stored_type grid_class")


class FileError(RuntimeError):
    """A file that cannot be listed or loaded: the message names the file
    and says what is wrong with it"""


@functools.lru_cache(maxsize=1)
def _library(path):
    try:
        lib = ctypes.CDLL(path)
    except OSError as e:
        raise FileError(f"nanovdb_mitsuba: cannot load {path} ({e}): install the package "
                        "(pip install .) or build the clone (README), or set NVDB_BUILD_DIR")
    lib.nvdb_grid_list_json.restype = ctypes.c_void_p
    lib.nvdb_grid_list_json.argtypes = [ctypes.c_char_p]
    lib.nvdb_grid_list_free.restype = None
    lib.nvdb_grid_list_free.argtypes = [ctypes.c_void_p]
    return lib


@functools.lru_cache(maxsize=64)
def _listing(path, _mtime_ns, _size):
    lib = _library(os.path.join(plugin_root(), "lib", "nanovdb_grid_list.so"))
    answer = lib.nvdb_grid_list_json(os.fsencode(path))
    if not answer:
        raise FileError(f'"{path}": cannot list its grids (out of memory)')
    try:
        reply = json.loads(ctypes.string_at(answer).decode("utf-8"))
    finally:
        lib.nvdb_grid_list_free(answer)
    if "error" in reply:
        raise FileError(reply["error"])
    return tuple(GridInfo(g["index"], g["name"], g["type"], g["stored_type"], g["class"])
                 for g in reply["grids"])


def list_grids(path):
    """[GridInfo] of a .nvdb or .vdb file's grids, in file order; FileError
    (naming the file) where it cannot be read. Cached per file version
    (its modification time and size)."""
    try:
        st = os.stat(path)
    except OSError as e:
        raise FileError(f'"{path}": ' + ("no such file" if not os.path.lexists(path)
                                         else e.strerror or str(e)))
    return list(_listing(os.fspath(path), st.st_mtime_ns, st.st_size))


def grid_rows(path):
    """[(name, type)] of list_grids(path): what fire.py's choices read"""
    return [(g.name, g.type) for g in list_grids(path)]


def grid_names(path):
    """The names of a file's grids, in file order"""
    return [g.name for g in list_grids(path)]


def plugin_message(error):
    """A Mitsuba error's message without its source location prefix
    ("[parser.cpp:1718] ... [NanoVDBVolume] "): nanovdbvolume's messages
    already name the file and the problem. Other messages stay whole, but
    for such a prefix."""
    msg = str(error)
    if "[NanoVDBVolume] " in msg:
        return msg.rsplit("[NanoVDBVolume] ", 1)[-1].strip()
    return msg.rsplit("] ", 1)[-1].strip() if msg.startswith("[") else msg.strip()


def load_volume(mi, path, grid="", filter_type="trilinear", level_set="fog",
                invalid_values="error"):
    """nanovdbvolume on `path` itself, in the grid's own world space
    (use_grid_transform): grid "" is the plugin's choice (the first float
    grid); level_set "fog" makes a level set a fog volume as vdb2nvdb does
    (.nvdb files too), "distance" keeps its distances. FileError with the
    plugin's message where it cannot load."""
    props = {"type": "nanovdbvolume", "filename": os.fspath(path), "use_grid_transform": True,
             "filter_type": filter_type, "invalid_values": invalid_values,
             "level_set": level_set}
    if grid:
        props["grid"] = grid
    try:
        return mi.load_dict(props)
    except RuntimeError as e:
        raise FileError(plugin_message(e))


def level_set_fogged(volume):
    """Whether a loaded nanovdbvolume is a file's level set made a fog volume"""
    import mitsuba as mi
    return bool(mi.traverse(volume)["level_set_fogged"])


def volume_properties(volume, path):
    """A loaded nanovdbvolume's facts (nanovdb_mitsuba.volume_facts), with
    "grid", the name of its grid in `path`, and "level_set_fogged"."""
    from .facts import volume_facts
    facts = volume_facts(volume)
    index = facts["grid_index"]
    names = grid_names(path) if index is not None else []
    facts["grid"] = names[index] if index is not None and index < len(names) else ""
    facts["level_set_fogged"] = level_set_fogged(volume)
    return facts
