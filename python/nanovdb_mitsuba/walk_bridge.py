"""The walk of a tracked medium for integrators written in Python
(prbvolpathlocal.py): volpathlocal.so's C functions
(src/integrators/walk_bridge.cpp), which take and return Dr.Jit variables by
index and so record into the caller's kernels, its symbolic loops included.

    bridge = WalkBridge.for_variant()          # the current variant's
    bridge.tracked(medium)                     # 0, 1 or 2 (tracked, emits)
    t, majorant = bridge.next_collision(medium, ray, tmax, u, active)
    t, majorant, sigma_s, sigma_t, throughput, L = bridge.fly(medium, ray, tmax, seed,
                                                              throughput, L, dL, active, primal)
    tr = bridge.transmit(medium, ray, tmax, seed, w, active, primal)
"""
import ctypes
import os

import drjit as dr
import mitsuba as mi

from . import plugin_root

_LIB = None


def _library():
    """volpathlocal.so, the one Mitsuba loads (its file resolver's): a
    second copy of the library would not know the first one's objects"""
    global _LIB
    if _LIB is None:
        path = str(mi.file_resolver().resolve("plugins/volpathlocal.so"))
        if not os.path.isabs(path) or not os.path.exists(path):
            path = os.path.join(plugin_root(), "plugins", "volpathlocal.so")
        if not os.path.exists(path):
            raise RuntimeError(f"nanovdb_mitsuba: {path} not found (the walk's C functions)")
        _LIB = ctypes.CDLL(path)
    return _LIB


def medium_index(medium):
    """A medium's registry index (what a MediumPtr holds)"""
    return int(dr.reinterpret_array(mi.UInt32, mi.MediumPtr(medium))[0])


def _spectrum(channels):
    """An UnpolarizedSpectrum of its channels (Floats)"""
    return mi.UnpolarizedSpectrum(*channels) if len(channels) > 1 else \
        mi.UnpolarizedSpectrum(channels[0])


class WalkBridge:
    """The C functions of one variant's backend"""

    _cache = {}

    @classmethod
    def for_variant(cls):
        variant = mi.variant()
        if variant not in cls._cache:
            cls._cache[variant] = cls(variant)
        return cls._cache[variant]

    def __init__(self, variant):
        if not ("_ad_" in variant and variant.split("_")[0] in ("llvm", "cuda")):
            raise RuntimeError(f"nanovdb_mitsuba: the walk bridge needs an llvm_ad_* or "
                               f"cuda_ad_* variant, not {variant}")
        lib = _library()
        backend = variant.split("_")[0]
        self.variant = variant.encode()
        self._tracked = getattr(lib, f"nvdb_walk_tracked_{backend}")
        self._tracked.argtypes = [ctypes.c_char_p, ctypes.c_uint32, ctypes.c_float,
                                  ctypes.c_char_p, ctypes.c_size_t]
        self._next = getattr(lib, f"nvdb_walk_next_collision_{backend}")
        self._next.argtypes = [ctypes.c_char_p, ctypes.c_uint32, ctypes.c_float, ctypes.c_float,
                               ctypes.POINTER(ctypes.c_uint64), ctypes.POINTER(ctypes.c_uint64),
                               ctypes.c_char_p, ctypes.c_size_t]
        self._fly = getattr(lib, f"nvdb_walk_fly_{backend}")
        self._fly.argtypes = [ctypes.c_char_p, ctypes.c_uint32, ctypes.c_float, ctypes.c_float,
                              ctypes.c_int, ctypes.POINTER(ctypes.c_uint64),
                              ctypes.POINTER(ctypes.c_uint64), ctypes.c_char_p, ctypes.c_size_t]
        self._transmit = getattr(lib, f"nvdb_walk_transmit_{backend}")
        self._transmit.argtypes = self._fly.argtypes
        self._release = getattr(lib, f"nvdb_walk_release_{backend}")
        self._release.argtypes = [ctypes.POINTER(ctypes.c_uint64), ctypes.c_size_t]
        for f in (self._tracked, self._next, self._fly, self._transmit):
            f.restype = ctypes.c_int
        self._release.restype = None

    @staticmethod
    def _indices(values):
        idx = []
        for v in values:
            idx += dr.detail.collect_indices(v)
        return (ctypes.c_uint64 * len(idx))(*idx)

    def _call(self, fn, name, *args):
        """fn's result (>= 0), or its message raised"""
        err = ctypes.create_string_buffer(512)
        r = fn(self.variant, *args, err, len(err))
        if r < 0:
            raise RuntimeError(f"nanovdb_mitsuba: {name}: {err.value.decode(errors='replace')}")
        return r

    def _outputs(self, out, templates):
        """The outputs as arrays of the templates' types (borrowed, then the
        C side's references handed back)"""
        values = dr.detail.update_indices(templates, list(out))
        self._release(out, len(out))
        return values

    def tracked(self, medium, max_ratio=1.0):
        """0: not tracked (the medium's own sample_interaction applies);
        1: tracked through local majorants; 2: tracked and emissive"""
        return self._call(self._tracked, "tracked", medium_index(medium), max_ratio)

    def next_collision(self, medium_id, ray, tmax, u, active, coarse_depth=2.0, headroom=1.0):
        """The first tentative collision along `ray` up to tmax, its optical
        depth -log(1 - u) under the walk's majorants times `headroom` (>= 1):
        (t, majorant), t infinite and majorant 0 where there is none.
        Detached."""
        inp = self._indices([mi.Point3f(ray.o), mi.Vector3f(ray.d), mi.Float(tmax),
                             mi.Float(u), mi.Bool(active)])
        out = (ctypes.c_uint64 * 2)()
        self._call(self._next, "next_collision", medium_id, coarse_depth, headroom, inp, out)
        return self._outputs(out, (mi.Float(), mi.Float()))

    def fly(self, medium_id, ray, tmax, seed, throughput, L, δL, active, primal,
            coarse_depth=2.0, headroom=1.0):
        """A path's free flight through the medium up to tmax: differential
        delta tracking through the walk (walk_bridge.cpp's fly() says what
        it adds to L, and backpropagates in the adjoint pass), its random
        numbers from PCG32 seeded with `seed` (UInt32, per lane). Returns
        (t, majorant, sigma_s, sigma_t, throughput, L) detached, t infinite
        where there is no real collision before tmax"""
        n = dr.size_v(mi.UnpolarizedSpectrum)
        v = self._walk(self._fly, "fly", medium_id, ray, tmax, seed, (throughput, L, δL), active,
                       primal, coarse_depth, headroom, 2 + 4 * n)
        return (v[0], v[1]) + tuple(_spectrum(v[2 + n * i: 2 + n * (i + 1)]) for i in range(4))

    def transmit(self, medium_id, ray, tmax, seed, w, active, primal, coarse_depth=2.0,
                 headroom=1.0):
        """A shadow ray's transmittance through the medium up to tmax:
        differential ratio tracking through the walk (walk_bridge.cpp's
        transmit(): in the adjoint pass each factor's derivative is
        backpropagated with weight w / factor), seeded as fly(). Returns it
        (detached)"""
        n = dr.size_v(mi.UnpolarizedSpectrum)
        return _spectrum(self._walk(self._transmit, "transmit", medium_id, ray, tmax, seed, (w,),
                                    active, primal, coarse_depth, headroom, n))

    def _walk(self, fn, name, medium_id, ray, tmax, seed, spectra, active, primal, coarse_depth,
              headroom, n_out):
        """fly()'s and transmit()'s call: their inputs in walk_bridge.cpp's
        order (Inputs), n_out Floats back"""
        values = [mi.Point3f(ray.o), mi.Vector3f(ray.d), mi.Float(ray.time)]
        if mi.is_spectral:
            values.append(ray.wavelengths)
        values += [mi.Float(tmax), mi.UInt32(seed)]
        values += [mi.UnpolarizedSpectrum(dr.detach(v)) for v in spectra] + [mi.Bool(active)]
        inp = self._indices(values)
        out = (ctypes.c_uint64 * n_out)()
        self._call(fn, name, medium_id, coarse_depth, headroom, int(bool(primal)), inp, out)
        return self._outputs(out, tuple(mi.Float() for _ in range(n_out)))
