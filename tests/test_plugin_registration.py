"""Each plugin registers every variant the build asked for, once, as its own
class: the plugins are compiled in parts, one per backend, and
src/plugin_entry.cpp's init_plugin() calls the parts
(include/nanovdb_mitsuba/plugin_variants.h). A part that registered another
backend's variants, or a stand-in (ObjectType Unknown) in place of the
class, would load in some variants and not in others.

The entry point is called here as Mitsuba's plugin manager calls it, with a
callback that records (variant, object type): through ctypes, with the
Itanium C++ ABI's std::string_view (a length and a pointer, passed by
value), so every variant is checked, CUDA's too, on a machine without a GPU.
"""
import ctypes

import pytest
import mitsuba as mi

from conftest import BUILD

PLUGINS = {"nanovdbvolume": "Volume", "volpathlocal": "Integrator",
           "emissiveheterogeneous": "Medium"}


def build_variants():
    """The variants the build compiled the plugins for (CMake's
    NVDB_VARIANTS; empty: all of the wheel's)"""
    cache = BUILD / "CMakeCache.txt"
    for line in cache.read_text().splitlines() if cache.exists() else []:
        if line.startswith("NVDB_VARIANTS:"):
            listed = line.split("=", 1)[1].strip()
            if listed:
                return listed.split(";")
    return list(mi.variants())


def registrations(plugin):
    """[(variant, ObjectType value)] in the order init_plugin registers them"""
    Callback = ctypes.CFUNCTYPE(None, ctypes.c_size_t, ctypes.c_void_p, ctypes.c_size_t,
                                ctypes.c_void_p, ctypes.c_uint32, ctypes.c_void_p)
    seen = []

    def record(id_len, id_ptr, variant_len, variant_ptr, object_type, make):
        assert ctypes.string_at(id_ptr, id_len).decode() == plugin
        assert make, "no constructor"
        seen.append((ctypes.string_at(variant_ptr, variant_len).decode(), object_type))

    callback = Callback(record)
    lib = ctypes.CDLL(str(BUILD / "plugins" / f"{plugin}.so"))
    lib.init_plugin.argtypes = [ctypes.c_size_t, ctypes.c_char_p, Callback]
    lib.init_plugin.restype = None
    lib.init_plugin(len(plugin), plugin.encode(), callback)
    return seen


@pytest.mark.parametrize("plugin", PLUGINS)
def test01_every_variant_once_as_its_class(variant_scalar_rgb, plugin):
    seen = registrations(plugin)
    expected_type = getattr(mi.ObjectType, PLUGINS[plugin]).value
    assert sorted(v for v, _ in seen) == sorted(build_variants()), seen
    assert all(t == expected_type for _, t in seen), seen
