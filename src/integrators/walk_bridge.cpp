/*
    src/integrators/walk_bridge.cpp -- the walk of a tracked medium, for
    integrators written in Python (nanovdb_mitsuba/prbvolpathlocal.py)

    Mitsuba writes its differentiable integrators in Python; ours
    (prbvolpathlocal, a marked copy of prbvolpath) tracks through the same
    local majorants as volpathlocal, through these C functions and the same
    code (tracking.h: span, begin_flight, next_collision; tracked_media.h:
    which media are tracked). They are C functions loaded with ctypes, as
    src/python/grid_list.cpp is (it says why not an extension module), and
    take and return Dr.Jit variables by index (drjit.detail.collect_indices
    / update_indices: the AD index in the upper 32 bits, the JIT index in
    the lower), so they run inside the caller's symbolic loops and record
    into its kernels. The walk's results are sampling quantities (a
    tentative collision and its majorant): they come back detached.
    eval_emission is the exception: its result carries the emission grid's
    gradients.

    Every function takes the variant's name (Mitsuba's, e.g. "llvm_ad_rgb")
    and a medium's registry index (a MediumPtr's value). One set per JIT
    backend, suffixed _llvm and _cuda, defined in the plugin's part for that
    backend (plugin_variants.h). Each returns 0, or -1 with a message in
    `err`.

    Output indices hold a reference each, which the caller hands back with
    nvdb_walk_release once it has borrowed them (update_indices).
*/

#include <mitsuba/core/ray.h>
#include <mitsuba/render/interaction.h>
#include <mitsuba/render/medium.h>

#include <nanovdb_mitsuba/emissive_medium.h>
#include <nanovdb_mitsuba/plugin_variants.h>

#include "tracked_media.h"
#include "tracking.h"

#include <cstdio>
#include <exception>
#include <string_view>

NAMESPACE_BEGIN(mitsuba)
namespace walk_bridge {

/// Whether this file compiles variant v (plugin_variants.h's choice)
constexpr bool compiled(std::string_view v) {
#if defined(NVDB_VARIANT_LIST) || defined(NVDB_PLUGIN_PART)
    return nvdb_detail::wanted(v);
#else
    return !v.empty();
#endif
}

template <typename Float, typename Spectrum> struct Bridge {
    MI_IMPORT_TYPES(Medium, MediumPtr)
    using Tracker = Tracking<Float, Spectrum>;
    using TrackedMedium = typename Tracker::TrackedMedium;
    using Flight = typename Tracker::Flight;

    static const Medium *medium(uint32_t id) {
        const char *variant = detail::variant<Float, Spectrum>::name;
        const Medium *m = (const Medium *) jit_registry_ptr(variant, "Medium", id);
        if (!m)
            Throw("no medium with registry index %u in variant %s", id, variant);
        return m;
    }

    /// (`checked`: tracked() said so before, for this scene)
    static bool track(uint32_t id, ScalarFloat max_ratio, TrackedMedium &k,
                      bool checked = false) {
        return TrackedMedia<Float, Spectrum>::track(medium(id), max_ratio, k, checked);
    }

    static Float in(uint64_t index) { return dr::detach(Float::borrow(index)); }

    /// 0: not tracked (its own sample_interaction applies); 1: tracked;
    /// 2: tracked, and it emits (EmissiveMedium)
    static int tracked(uint32_t id, float max_ratio) {
        TrackedMedium k;
        if (!track(id, max_ratio, k))
            return 0;
        return k.emissive ? 2 : 1;
    }

    /**
     * The first tentative collision along the ray (in: o xyz, d xyz, tmax,
     * u, active) through the tracked medium, its optical depth to it being
     * -log(1 - u) under the walk's majorants: out: its distance t (infinity
     * where the walk ends before tmax, or the ray misses the medium) and
     * the majorant there (scale times the segment's bound; 0 where none).
     * A new tentative collision from a null one is this from there (the
     * Poisson process of tentative collisions has no memory). `headroom`
     * (>= 1) multiplies every majorant: at scale x bound x headroom the
     * optical depth -log(1 - u) is -log(1 - u) / headroom under the walk's.
     */
    static void next_collision(uint32_t id, float coarse_depth, float headroom,
                               const uint64_t *idx, uint64_t *out) {
        TrackedMedium k;
        if (!track(id, 1.f, k, true))
            Throw("the medium is not tracked through local majorants");
        Ray3f ray;
        ray.o = Point3f(in(idx[0]), in(idx[1]), in(idx[2]));
        ray.d = Vector3f(in(idx[3]), in(idx[4]), in(idx[5]));
        Float tmax = in(idx[6]), u = in(idx[7]);
        Mask active = Mask::borrow(idx[8]);
        auto [mint, maxt, wr] = Tracker::span(k, ray, tmax, dr::opaque<Float>(coarse_depth),
                                              active);
        // (headroom: every majorant times it, i.e. the scale's rate of
        // tentative collisions; tau against the walk's own majorants)
        Flight f = Tracker::begin_flight(k, wr, mint, maxt, -dr::log(1.f - u) / headroom, active,
                                         false);
        Tracker::next_collision(k, wr, f, false);
        Float t = dr::select(f.alive, f.t, dr::Infinity<Float>),
              majorant = dr::select(f.alive, headroom * Tracker::rate(k, f.walk, false).first, 0.f);
        out[0] = t.release();
        out[1] = majorant.release();
    }

    /// The emitted radiance Le of an emissive medium at points (in: p xyz,
    /// time, the wavelengths, active), out: its channels, attached to the
    /// emission grid (their gradients reach its values)
    static void eval_emission(uint32_t id, const uint64_t *idx, uint64_t *out) {
        TrackedMedium k;
        if (!track(id, 1.f, k, true) || !k.emissive)
            Throw("the medium does not emit");
        MediumInteraction3f mei = dr::zeros<MediumInteraction3f>();
        mei.p = Point3f(in(idx[0]), in(idx[1]), in(idx[2]));
        mei.time = in(idx[3]);
        size_t n = 4;
        if constexpr (is_spectral_v<Spectrum>)
            for (size_t c = 0; c < dr::size_v<Wavelength>; ++c)
                mei.wavelengths[c] = in(idx[n++]);
        mei.medium = MediumPtr(k.medium);
        Mask active = Mask::borrow(idx[n]);
        UnpolarizedSpectrum le = k.emissive->eval_emission(mei, active);
        for (size_t c = 0; c < dr::size_v<UnpolarizedSpectrum>; ++c)
            out[c] = UnpolarizedSpectrum(le)[c].release();
    }
};

template <typename Fn> int guarded(char *err, size_t err_len, Fn &&fn) {
    try {
        return fn();
    } catch (const std::exception &e) {
        if (err && err_len)
            std::snprintf(err, err_len, "%s", e.what());
        return -1;
    }
}

inline int unknown(char *err, size_t err_len, std::string_view variant) {
    if (err && err_len)
        std::snprintf(err, err_len, "variant %.*s is not compiled in this plugin "
                      "(an AD variant of this backend is needed)", (int) variant.size(),
                      variant.data());
    return -1;
}

} // namespace walk_bridge
NAMESPACE_END(mitsuba)

// One set of C functions per backend: FN(variant name, Float, Spectrum) for
// each AD variant the bridge serves (prbvolpath's: not the polarized ones)
NAMESPACE_BEGIN(mitsuba)
namespace walk_bridge {
template <JitBackend B> using F = dr::DiffArray<B, float>;
using LlvmRgb = Color<F<JitBackend::LLVM>, 3>;
using LlvmMono = Color<F<JitBackend::LLVM>, 1>;
using LlvmSpectral = Spectrum<F<JitBackend::LLVM>, 4>;
using CudaRgb = Color<F<JitBackend::CUDA>, 3>;
using CudaMono = Color<F<JitBackend::CUDA>, 1>;
using CudaSpectral = Spectrum<F<JitBackend::CUDA>, 4>;
} // namespace walk_bridge
NAMESPACE_END(mitsuba)
#define NVDB_BRIDGE_LLVM_VARIANTS(FN)                                                   \
    FN("llvm_ad_rgb", F<JitBackend::LLVM>, LlvmRgb)                                       \
    FN("llvm_ad_mono", F<JitBackend::LLVM>, LlvmMono)                                     \
    FN("llvm_ad_spectral", F<JitBackend::LLVM>, LlvmSpectral)
#define NVDB_BRIDGE_CUDA_VARIANTS(FN)                                                   \
    FN("cuda_ad_rgb", F<JitBackend::CUDA>, CudaRgb)                                       \
    FN("cuda_ad_mono", F<JitBackend::CUDA>, CudaMono)                                     \
    FN("cuda_ad_spectral", F<JitBackend::CUDA>, CudaSpectral)

// (a variant this file does not compile answers "not compiled")
#define NVDB_BRIDGE_DISPATCH(name, F, S, CALL)                                            \
    if (v == name) {                                                                      \
        if constexpr (mitsuba::walk_bridge::compiled(name)) {                             \
            using namespace mitsuba::walk_bridge;                                         \
            using B = Bridge<F, S>;                                 \
            CALL;                                                                         \
        } else                                                                            \
            return mitsuba::walk_bridge::unknown(err, err_len, v);                        \
    }
#define NVDB_BRIDGE_TRACKED(name, F, S)                                                   \
    NVDB_BRIDGE_DISPATCH(name, F, S, return B::tracked(id, max_ratio))
#define NVDB_BRIDGE_NEXT(name, F, S)                                                      \
    NVDB_BRIDGE_DISPATCH(name, F, S, B::next_collision(id, coarse_depth, headroom, in, out); \
                         return 0)
#define NVDB_BRIDGE_EMISSION(name, F, S)                                                  \
    NVDB_BRIDGE_DISPATCH(name, F, S, B::eval_emission(id, in, out); return 0)

#define NVDB_BRIDGE_FUNCTIONS(suffix, VARIANTS)                                            \
    extern "C" MI_EXPORT int nvdb_walk_tracked_##suffix(const char *variant, uint32_t id,  \
                                                         float max_ratio, char *err,        \
                                                         size_t err_len) {                 \
        std::string_view v(variant);                                                       \
        return mitsuba::walk_bridge::guarded(err, err_len, [&]() -> int {                  \
            VARIANTS(NVDB_BRIDGE_TRACKED)                                                  \
            return mitsuba::walk_bridge::unknown(err, err_len, v);                         \
        });                                                                                \
    }                                                                                      \
    extern "C" MI_EXPORT int nvdb_walk_next_collision_##suffix(                            \
        const char *variant, uint32_t id, float coarse_depth, float headroom,              \
        const uint64_t *in, uint64_t *out, char *err, size_t err_len) {                    \
        std::string_view v(variant);                                                       \
        return mitsuba::walk_bridge::guarded(err, err_len, [&]() -> int {                  \
            VARIANTS(NVDB_BRIDGE_NEXT)                                                     \
            return mitsuba::walk_bridge::unknown(err, err_len, v);                         \
        });                                                                                \
    }                                                                                      \
    extern "C" MI_EXPORT int nvdb_walk_eval_emission_##suffix(                             \
        const char *variant, uint32_t id, const uint64_t *in, uint64_t *out, char *err,    \
        size_t err_len) {                                                                  \
        std::string_view v(variant);                                                       \
        return mitsuba::walk_bridge::guarded(err, err_len, [&]() -> int {                  \
            VARIANTS(NVDB_BRIDGE_EMISSION)                                                 \
            return mitsuba::walk_bridge::unknown(err, err_len, v);                         \
        });                                                                                \
    }                                                                                      \
    /* Hands back the references of output indices (each once) */                          \
    extern "C" MI_EXPORT void nvdb_walk_release_##suffix(const uint64_t *indices, size_t n) { \
        for (size_t i = 0; i < n; ++i)                                                     \
            (void) dr::DiffArray<JitBackend::LLVM, float>::steal(indices[i]);              \
    }

// The LLVM part (or, not built in parts, the only file): the LLVM set; the
// CUDA part: the CUDA set; the scalar part: none
#if !defined(NVDB_PLUGIN_PART) || NVDB_PLUGIN_PART == 2
NVDB_BRIDGE_FUNCTIONS(llvm, NVDB_BRIDGE_LLVM_VARIANTS)
#endif
#if !defined(NVDB_PLUGIN_PART) || NVDB_PLUGIN_PART == 3
NVDB_BRIDGE_FUNCTIONS(cuda, NVDB_BRIDGE_CUDA_VARIANTS)
#endif
