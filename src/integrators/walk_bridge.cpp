/*
    src/integrators/walk_bridge.cpp -- the walk of a tracked medium, for
    integrators written in Python (nanovdb_mitsuba/prbvolpathlocal.py)

    Mitsuba writes its differentiable integrators in Python; ours
    (prbvolpathlocal, a marked copy of prbvolpath) tracks through the same
    local majorants as volpathlocal, through these C functions and the same
    code (tracking.h: span, sample_t_maj; tracked_media.h: which media are
    tracked): fly() (a path's free flight) and transmit() (a shadow ray's
    transmittance), each one walk with its adjoint inside; next_collision()
    (one tentative collision: the tests' probe of the walk's majorants).
    They are C functions loaded with ctypes, as
    src/python/grid_list.cpp is (it says why not an extension module), and
    take and return Dr.Jit variables by index (drjit.detail.collect_indices
    / update_indices: the AD index in the upper 32 bits, the JIT index in
    the lower), so they run inside the caller's symbolic loops and record
    into its kernels. What comes back is detached: the walk's results are
    sampling quantities (a tentative collision and its majorant), and
    fly() and transmit() backpropagate their estimators' derivatives
    themselves, in the caller's AD scope (the adjoint pass).

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

    /// The random source of fly() and transmit(): PCG32, seeded per lane by the caller's
    /// sampler (so the adjoint pass, whose sampler replays the primal
    /// one's, replays the flight)
    struct Rng {
        dr::PCG32<UInt32> pcg;
        Float next_1d(const Mask &active) { return pcg.next_float32(active); }
        DRJIT_STRUCT(Rng, pcg)
    };

    /// The inputs fly() and transmit() share: the medium, the ray (o xyz,
    /// d xyz, time, [wavelengths]), tmax and the PCG32 seed; then, in
    /// order, the caller's spectra (a channel each) and the active mask
    struct Inputs {
        TrackedMedium k;
        Ray3f ray;
        Float tmax;
        Rng rng;
        const uint64_t *idx;
        size_t n = 0;

        Inputs(uint32_t id, const uint64_t *idx_) : idx(idx_) {
            if (!track(id, 1.f, k, true))
                Throw("the medium is not tracked through local majorants");
            // (one at a time: the order of a call's arguments is unspecified)
            for (size_t c = 0; c < 3; ++c)
                ray.o[c] = next();
            for (size_t c = 0; c < 3; ++c)
                ray.d[c] = next();
            ray.time = next();
            if constexpr (is_spectral_v<Spectrum>)
                for (size_t c = 0; c < dr::size_v<Wavelength>; ++c)
                    ray.wavelengths[c] = next();
            tmax = next();
            rng.pcg.seed(UInt64(dr::detach(UInt32::borrow(idx[n++]))),
                         UInt64(0xda3e39cb94b95bdbULL));
        }
        Float next() { return in(idx[n++]); }
        UnpolarizedSpectrum spectrum() {
            UnpolarizedSpectrum v;
            for (size_t c = 0; c < dr::size_v<UnpolarizedSpectrum>; ++c)
                v[c] = next();
            return v;
        }
        Mask mask() { return Mask::borrow(idx[n++]); }
    };

    /// Releases a spectrum's channels into out[o..]
    static void put(const UnpolarizedSpectrum &v, uint64_t *out, size_t &o) {
        for (size_t c = 0; c < dr::size_v<UnpolarizedSpectrum>; ++c)
            out[o++] = Float(v[c]).release();
    }

    /**
     * prbvolpathlocal's free flight of a path through the tracked medium
     * (its `fly_tracked`): prbvolpath's differential delta tracking, its
     * tentative collisions at the walk's majorants times `headroom`, in
     * one walk (tracking.h's sample_t_maj), from the ray's origin up to
     * tmax. At each tentative collision at t, with mu the rate there:
     *  - an emissive medium's sigma_a Le / mu times the throughput is
     *    added to L (primal) or taken from it (adjoint), and in the
     *    adjoint pass backpropagated with weight dL;
     *  - with probability P = mean(sigma_t) / mu (detached) the collision
     *    is real, its weight sigma_s / (mu P), else null, its weight
     *    (mu - sigma_t) / (mu (1 - P)) (the coefficients attached). The
     *    throughput takes the weight's value; in the adjoint pass its
     *    derivative is backpropagated with the radiance still to come,
     *    dL x weight x detach(L / weight) (prbvolpath's rule, one
     *    tentative collision per loop iteration there). The flight stops
     *    at the real collision.
     * The medium's lookups are its own (get_scattering_coefficients; a
     * stochastic filter's voxel comes from the position), as the
     * integrator's elsewhere. Which pass: `primal`; the AD scope is the
     * caller's.
     *
     * in: o xyz, d xyz, time, [wavelengths], tmax, seed (UInt32: PCG32's
     * state, one per lane), throughput, L, dL (a channel each), active.
     * out: t (infinity: no real collision before tmax), the majorant
     * there (mu), sigma_s, sigma_t (detached), throughput, L.
     */
    static void fly(uint32_t id, float coarse_depth, float headroom, bool primal,
                    const uint64_t *idx, uint64_t *out) {
        dr::suspend_grad<Float> no_graph(primal); // (the primal pass wants no derivatives)
        Inputs a(id, idx);
        UnpolarizedSpectrum throughput = a.spectrum(), L = a.spectrum(), dL = a.spectrum();
        Mask active = a.mask();
        TrackedMedium &k = a.k;
        const Ray3f &ray = a.ray;
        auto [mint, maxt, wr] = Tracker::span(k, ray, a.tmax, dr::opaque<Float>(coarse_depth),
                                              active);
        Rng rng = a.rng;
        struct State {
            UnpolarizedSpectrum throughput, L, sigma_s, sigma_t;
            Float majorant;
            Mask real;
            DRJIT_STRUCT(State, throughput, L, sigma_s, sigma_t, majorant, real)
        } st = { throughput, L, dr::zeros<UnpolarizedSpectrum>(), dr::zeros<UnpolarizedSpectrum>(),
                 Float(0.f), Mask(false) };
        Flight f = Tracker::sample_t_maj(
            k, wr, mint, maxt, rng, st, DeltaLoop, active,
            [k, ray, mint, dL, primal](State &s, const Flight &f_, const Float &mu,
                                       const Float & /* c */, Rng &rng_, const Mask &hit) {
                MediumInteraction3f mei = Tracker::interaction_at(k, ray, f_.t, mint);
                auto [sigma_s, sigma_n, sigma_t] = k.medium->get_scattering_coefficients(mei, hit);
                DRJIT_MARK_USED(sigma_n);
                if (k.emissive) { // (traced only for an emissive medium)
                    UnpolarizedSpectrum contrib = dr::select(
                        hit, s.throughput * (sigma_t - sigma_s) *
                                 k.emissive->eval_emission(mei, hit) / mu, 0.f);
                    s.L += dr::detach(primal ? contrib : -contrib);
                    if (!primal && dr::grad_enabled(contrib)) {
                        UnpolarizedSpectrum g = dL * contrib;
                        dr::backward_from(g);
                    }
                }
                Float xi = rng_.next_1d(hit),
                      p_real = dr::mean(dr::detach(sigma_t)) / mu;
                Mask real = hit && (xi < p_real);
                // (the branch not taken must not divide by 0: its
                // adjoint would be 0 x Inf)
                Float p_safe = dr::maximum(p_real, 1e-30f),
                      q_safe = dr::maximum(1.f - p_real, 1e-30f);
                UnpolarizedSpectrum weight = dr::select(
                    hit, dr::select(real, sigma_s / (mu * p_safe),
                                    (mu - sigma_t) / (mu * q_safe)), 1.f);
                if (!primal && dr::grad_enabled(weight)) {
                    UnpolarizedSpectrum g =
                        dL * weight *
                        dr::detach(dr::select(hit, s.L / dr::maximum(1e-8f, weight), 0.f));
                    dr::backward_from(g);
                }
                s.throughput *= dr::detach(weight);
                dr::masked(s.sigma_s, real) = dr::detach(sigma_s);
                dr::masked(s.sigma_t, real) = dr::detach(sigma_t);
                dr::masked(s.majorant, real) = mu;
                s.real |= real;
                return !real;
            },
            "prbvolpathlocal: free flight", false, nullptr, headroom);
        Float t = dr::select(st.real, f.t, dr::Infinity<Float>);
        out[0] = t.release();
        out[1] = st.majorant.release();
        size_t o = 2;
        for (UnpolarizedSpectrum *v : { &st.sigma_s, &st.sigma_t, &st.throughput, &st.L })
            put(*v, out, o);
    }

    /**
     * prbvolpathlocal's transmittance of a shadow ray through the tracked
     * medium (its sample_emitter): prbvolpath's differential ratio
     * tracking, its tentative collisions at the walk's majorants times
     * `headroom`, in one walk from the ray's origin up to tmax. Each
     * tentative collision multiplies the estimate by f = 1 - sigma_t / mu
     * (per channel, sigma_t attached); in the adjoint pass f's derivative
     * is backpropagated with weight detach(w / f), w the caller's dL x the
     * contribution this transmittance is a factor of (prbvolpath's rule).
     * The walk stops where the estimate is 0 in every channel.
     *
     * in: o xyz, d xyz, time, [wavelengths], tmax, seed, w (a channel
     * each), active. out: the estimate (detached; 1 where inactive).
     */
    static void transmit(uint32_t id, float coarse_depth, float headroom, bool primal,
                         const uint64_t *idx, uint64_t *out) {
        // (the primal pass, and the adjoint pass's primal-mode call of
        // sample_emitter, want no derivatives: no AD graph for them)
        dr::suspend_grad<Float> no_graph(primal);
        Inputs a(id, idx);
        UnpolarizedSpectrum w = a.spectrum();
        Mask active = a.mask();
        TrackedMedium &k = a.k;
        const Ray3f &ray = a.ray;
        auto [mint, maxt, wr] = Tracker::span(k, ray, a.tmax, dr::opaque<Float>(coarse_depth),
                                              active);
        UnpolarizedSpectrum tr(1.f);
        Tracker::sample_t_maj(
            k, wr, mint, maxt, a.rng, tr, RatioLoop, active,
            [k, ray, mint, w, primal](UnpolarizedSpectrum &tr_, const Flight &f_, const Float &mu,
                                      const Float & /* c */, Rng &, const Mask &hit) {
                MediumInteraction3f mei = Tracker::interaction_at(k, ray, f_.t, mint);
                auto [sigma_s, sigma_n, sigma_t] = k.medium->get_scattering_coefficients(mei, hit);
                DRJIT_MARK_USED(sigma_s);
                DRJIT_MARK_USED(sigma_n);
                UnpolarizedSpectrum f = dr::select(hit, 1.f - sigma_t / mu, 1.f);
                if (!primal && dr::grad_enabled(f)) {
                    UnpolarizedSpectrum g =
                        f * dr::detach(dr::select(hit && (f > 0.f), w / f, 0.f));
                    dr::backward_from(g);
                }
                tr_ *= dr::detach(f);
                return dr::any(tr_ != 0.f);
            },
            "prbvolpathlocal: ratio tracking", false, nullptr, headroom);
        size_t o = 0;
        put(tr, out, o);
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

/// A Bridge type, passed to a generic lambda
template <typename B> struct Tag { using type = B; };

// The AD variants the bridge serves per backend (prbvolpath's: not the
// polarized ones), FN(variant name, Float, Spectrum) each
template <JitBackend B> using F = dr::DiffArray<B, float>;
using LlvmRgb = Color<F<JitBackend::LLVM>, 3>;
using LlvmMono = Color<F<JitBackend::LLVM>, 1>;
using LlvmSpectral = Spectrum<F<JitBackend::LLVM>, 4>;
using CudaRgb = Color<F<JitBackend::CUDA>, 3>;
using CudaMono = Color<F<JitBackend::CUDA>, 1>;
using CudaSpectral = Spectrum<F<JitBackend::CUDA>, 4>;
using LlvmFloat = F<JitBackend::LLVM>;
using CudaFloat = F<JitBackend::CUDA>;
#define NVDB_BRIDGE_LLVM_VARIANTS(FN)                                                   \
    FN("llvm_ad_rgb", LlvmFloat, LlvmRgb)                                                 \
    FN("llvm_ad_mono", LlvmFloat, LlvmMono)                                               \
    FN("llvm_ad_spectral", LlvmFloat, LlvmSpectral)
#define NVDB_BRIDGE_CUDA_VARIANTS(FN)                                                   \
    FN("cuda_ad_rgb", CudaFloat, CudaRgb)                                                 \
    FN("cuda_ad_mono", CudaFloat, CudaMono)                                               \
    FN("cuda_ad_spectral", CudaFloat, CudaSpectral)

// fn(Tag<Bridge<Float, Spectrum>>) for the variant named, its exceptions
// as a message in err; a variant this file does not compile answers "not
// compiled" (its Bridge is never instantiated)
#define NVDB_BRIDGE_CASE(name, Float_, Spectrum_)                                         \
    if (v == name) {                                                                      \
        if constexpr (compiled(name))                                                     \
            return fn(Tag<Bridge<Float_, Spectrum_>>{});                                  \
        else                                                                              \
            return unknown(err, err_len, v);                                              \
    }
#define NVDB_BRIDGE_DISPATCH(suffix, VARIANTS)                                            \
    template <typename Fn>                                                                \
    int dispatch_##suffix(const char *variant, char *err, size_t err_len, Fn &&fn) {      \
        std::string_view v(variant);                                                      \
        return guarded(err, err_len, [&]() -> int {                                       \
            VARIANTS(NVDB_BRIDGE_CASE)                                                    \
            return unknown(err, err_len, v);                                              \
        });                                                                               \
    }
NVDB_BRIDGE_DISPATCH(llvm, NVDB_BRIDGE_LLVM_VARIANTS)
NVDB_BRIDGE_DISPATCH(cuda, NVDB_BRIDGE_CUDA_VARIANTS)

} // namespace walk_bridge
NAMESPACE_END(mitsuba)

// One set of C functions per backend (walk_bridge.py's argtypes)
#define NVDB_BRIDGE_FUNCTIONS(suffix)                                                      \
    extern "C" MI_EXPORT int nvdb_walk_tracked_##suffix(const char *variant, uint32_t id,  \
                                                         float max_ratio, char *err,        \
                                                         size_t err_len) {                 \
        return mitsuba::walk_bridge::dispatch_##suffix(variant, err, err_len, [&](auto b) { \
            return decltype(b)::type::tracked(id, max_ratio);                              \
        });                                                                                \
    }                                                                                      \
    extern "C" MI_EXPORT int nvdb_walk_next_collision_##suffix(                            \
        const char *variant, uint32_t id, float coarse_depth, float headroom,              \
        const uint64_t *in, uint64_t *out, char *err, size_t err_len) {                    \
        return mitsuba::walk_bridge::dispatch_##suffix(variant, err, err_len, [&](auto b) { \
            decltype(b)::type::next_collision(id, coarse_depth, headroom, in, out);        \
            return 0;                                                                      \
        });                                                                                \
    }                                                                                      \
    extern "C" MI_EXPORT int nvdb_walk_fly_##suffix(                                       \
        const char *variant, uint32_t id, float coarse_depth, float headroom, int primal,  \
        const uint64_t *in, uint64_t *out, char *err, size_t err_len) {                    \
        return mitsuba::walk_bridge::dispatch_##suffix(variant, err, err_len, [&](auto b) { \
            decltype(b)::type::fly(id, coarse_depth, headroom, primal != 0, in, out);      \
            return 0;                                                                      \
        });                                                                                \
    }                                                                                      \
    extern "C" MI_EXPORT int nvdb_walk_transmit_##suffix(                                  \
        const char *variant, uint32_t id, float coarse_depth, float headroom, int primal,  \
        const uint64_t *in, uint64_t *out, char *err, size_t err_len) {                    \
        return mitsuba::walk_bridge::dispatch_##suffix(variant, err, err_len, [&](auto b) { \
            decltype(b)::type::transmit(id, coarse_depth, headroom, primal != 0, in, out); \
            return 0;                                                                      \
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
NVDB_BRIDGE_FUNCTIONS(llvm)
#endif
#if !defined(NVDB_PLUGIN_PART) || NVDB_PLUGIN_PART == 3
NVDB_BRIDGE_FUNCTIONS(cuda)
#endif
