/*
    src/integrators/tracking.h -- tracking through a medium whose volume
    offers local majorants (nanovdb_mitsuba/local_majorants.h): the seam
    between the walk, which knows the tree, and the estimators, which know
    the physics (pbrt-v4's SampleT_maj and its callers, in Dr.Jit)

      sample_t_maj()   tentative collisions along a ray, segment by segment of
                       the walk: at rate mu(t) = scale x the segment's bound,
                       i.e. with density mu(t) exp(-int_0^t mu). At each it
                       calls the estimator's `collide`, which says whether the
                       lane goes on.
      delta_tracking() the first real collision (the path's free flight), and
                       an emissive medium's emission along the way
      ratio_tracking() the transmittance estimate (shadow rays): ratio
                       tracking, or residual ratio tracking against the
                       walk's controls (the default; see there)

    Both estimators are unbiased for any majorant that bounds the medium's
    extinction (each segment's bound does, scale times the largest value a
    lookup can return there, filter footprint included: majorant_walk.h).
    Every loop has a bound a valid ray cannot reach (loop_bounds.h): the
    walk's steps and the tentative collisions per flight, set here.
*/

#pragma once

#include <mitsuba/core/ray.h>
#include <mitsuba/render/interaction.h>
#include <mitsuba/render/medium.h>
#include <mitsuba/render/sampler.h>

#include <nanovdb_mitsuba/emissive_medium.h>
#include <nanovdb_mitsuba/local_majorants.h>

#include "loop_bounds.h"

#include <tuple>

NAMESPACE_BEGIN(mitsuba)

template <typename Float, typename Spectrum> struct Tracking {
    MI_IMPORT_TYPES(Medium, MediumPtr, Sampler)
    using Majorants = LocalMajorants<Float, Spectrum>;
    using Walk = typename Majorants::Walk;
    using WalkRay = typename Majorants::WalkRay;
    using Emissive = EmissiveMedium<Float, Spectrum>;

    /// A medium tracked through its volume's local majorants
    struct TrackedMedium {
        const Medium *medium;
        const Majorants *volume;
        // The scene's values reach kernels as opaque variables, not as
        // literals, so that scenes of other scales share compiled kernels
        Float scale;              ///< the medium's density scale (> 0)
        Float max_majorant;       ///< scale x the largest segment bound
        bool stochastic;          ///< its lookups take random offsets (stochastic filters)
        const Emissive *emissive; ///< the medium's emission (nullptr: it emits none)
        /// Next-event estimation samples its emission (volpathlocal's
        /// emission_sampling), choosing it with probability `select`
        bool nee = false;
        Float select = 0.f;
    };

    /**
     * MIS of the emission a flight collects against next-event estimation
     * from the path's last scattering vertex (docs/research/issue35_nee.md):
     * where `on`, the emission at x is weighted by
     *     p_dir^2 / (p_dir^2 + p_nee^2),   p_nee = select pdf(x) |x - origin|^2,
     * Veach's power heuristic (beta 2) with a deterministic stand-in (1) for
     * the flight's probability of reaching x; next-event estimation weighs
     * its sample with the complement, so the two sum to one for every x and
     * both stay unbiased. The power heuristic over the balance heuristic:
     * on the fireball over a floor, the floor's variance 0.147 against
     * 0.169 of collisions-only's, the smoke's 0.273 against 0.283, same
     * seeds. `nee_only` gives the flight weight 0 where `on` (next-event
     * estimation alone covers it: tests)
     */
    /// Veach's power heuristic (beta 2): the weight of a sample of density
    /// a against another technique's density b for the same point; the
    /// arithmetic of volpath's mis_weight(), which next-event estimation's
    /// side (volpathlocal's sample_emissive_media) calls, so that the two
    /// weights of a point sum to 1
    static Float power_heuristic(Float a, Float b) {
        a *= a;
        b *= b;
        Float w = a / (a + b);
        return dr::select(dr::isfinite(w), w, 0.f);
    }

    struct EmissionMis {
        Mask on;
        Point3f origin;
        Float dir_pdf;
        bool nee_only = false;
    };

    /// A flight through a tracked medium: the walk, the position t along the
    /// ray, and the optical depth tau left to the next tentative collision
    struct Flight {
        Mask alive;     ///< false once the walk has ended (or the estimator stopped)
        Mask searching; ///< inside next_collision(): not yet at a collision
        Walk walk;
        Float t, tau;
        Float control_depth;               ///< residual: the controls' optical depth so far
        Float extra;                       ///< a rate added where the segment's bound is > 0
                                           ///< (camera_tracking; else 0, untraced)
        UInt32 steps, collisions;          ///< walk steps, tentative collisions so far
        UInt32 max_steps, max_collisions;  ///< their bounds
        UInt32 tripped;                    ///< the bounds that stopped it (bits)
        DRJIT_STRUCT(Flight, alive, searching, walk, t, tau, control_depth, extra, steps,
                     collisions, max_steps, max_collisions, tripped)
    };

    /// The parameter range of `ray` inside the medium's box, up to tmax
    static std::pair<Float, Float> medium_range(const TrackedMedium &k, const Ray3f &ray,
                                                const Float &tmax, Mask &active) {
        auto [hit, mint, maxt] = k.medium->intersect_aabb(ray);
        mint = dr::maximum(mint, 0.f);
        maxt = dr::minimum(maxt, tmax);
        active &= hit && (mint < maxt);
        return { mint, maxt };
    }

    /// What both trackers start from: the range of `ray` in the medium (up
    /// to tmax; lanes that miss it leave `active`) and the ray in the walk's
    /// space, whose nodes are crossed whole below an optical depth of
    /// coarse_depth
    static std::tuple<Float, Float, WalkRay> span(const TrackedMedium &k, const Ray3f &ray,
                                                  const Float &tmax, const Float &coarse_depth,
                                                  Mask &active) {
        auto [mint, maxt] = medium_range(k, ray, tmax, active);
        WalkRay wr = k.volume->walk_ray(ray, coarse_depth / k.scale, active);
        return { mint, maxt, wr };
    }

    /// A medium interaction at distance t along the ray, for evaluating the
    /// medium there and scattering from it
    static MediumInteraction3f interaction_at(const TrackedMedium &k, const Ray3f &ray,
                                              const Float &t, const Float &mint) {
        MediumInteraction3f mei = dr::zeros<MediumInteraction3f>();
        mei.wi = -ray.d;
        mei.sh_frame = Frame3f(mei.wi);
        mei.time = ray.time;
        mei.wavelengths = ray.wavelengths;
        mei.t = t;
        mei.p = ray(t);
        mei.medium = MediumPtr(k.medium);
        mei.mint = mint;
        return mei;
    }

    /// The medium's coefficients (sigma_s, sigma_n, sigma_t) at `mei`. A
    /// volume with a stochastic filter reads one voxel drawn with offsets
    /// from the sampler (three numbers per tentative collision; none
    /// otherwise), given to it for this call only
    static auto coefficients(const TrackedMedium &k, const MediumInteraction3f &mei,
                             Sampler *sampler, const Mask &hit) {
        if (!k.stochastic)
            return k.medium->get_scattering_coefficients(mei, hit);
        Point2f u2 = sampler->next_2d(hit);
        Vector3f u(u2.x(), u2.y(), sampler->next_1d(hit));
        struct Scope { // (cleared on every way out)
            const Majorants *v;
            ~Scope() { v->set_lookup_offsets(nullptr); }
        } scope{ k.volume };
        k.volume->set_lookup_offsets(&u);
        return k.medium->get_scattering_coefficients(mei, hit);
    }

    /// A float bound as an iteration count (NaN, infinity and >= 2^31: 2^31)
    static UInt32 to_bound(const Float &n) {
        return dr::select(n < 2147483648.f, UInt32(dr::maximum(n, 0.f)), UInt32(1u << 31));
    }

    /**
     * The rate of tentative collisions in the walk's current segment, and
     * the control that tracking subtracts there (both times the scale).
     * Plain tracking: the majorant M, and 0. Residual (the walk's controls):
     * the residual's bound max(M - c, c - L) with c the control and L the
     * lower bound, so that |mu_t - c| <= rate wherever the bounds hold;
     * never below M / 1024, so that a cell whose values the table's 4 bits
     * round to one constant is still sampled (a rate of 0 would drop
     * whatever differs from c there).
     */
    static std::pair<Float, Float> rate(const TrackedMedium &k, const Walk &w, bool residual,
                                        const Float *extra = nullptr) {
        if (extra) // (camera_tracking: plain tracking at a higher rate)
            return { k.scale * w.majorant + dr::select(w.majorant > 0.f, *extra, 0.f),
                     Float(0.f) };
        if (!residual)
            return { k.scale * w.majorant, Float(0.f) };
        Float r = dr::maximum(dr::maximum(w.majorant - w.control, w.control - w.minorant),
                              w.majorant * (1.f / 1024.f));
        return { k.scale * r, k.scale * w.control };
    }

    /// A flight over [mint, maxt], tau the optical depth to its first
    /// tentative collision, and its loop bounds (residual: its walk gives
    /// the controls)
    static Flight begin_flight(const TrackedMedium &k, const WalkRay &wr, const Float &mint,
                               const Float &maxt, const Float &tau, const Mask &active,
                               bool residual, const Float *extra = nullptr,
                               float rate_factor = 1.f) {
        Flight f;
        f.alive = active;
        f.searching = false;
        f.walk = k.volume->walk_begin(wr, mint, maxt, active, residual);
        f.t = mint;
        f.control_depth = 0.f;
        f.extra = extra ? *extra : Float(0.f);
        f.tau = tau;
        f.steps = f.collisions = f.tripped = 0;
        // Walk steps: every step crosses a cell face, and cells are at least
        // 8 voxels wide, so a segment crosses at most sum_a |d_a| len / 8 + 3
        // of them; twice that, and 64 for round-off
        Float len = dr::maximum(maxt - mint, 0.f),
              faces = (dr::abs(wr.direction.x()) + dr::abs(wr.direction.y()) +
                       dr::abs(wr.direction.z())) * len * 0.125f + 3.f;
        f.max_steps = to_bound(2.f * faces + 64.f);
        // Tentative collisions: Poisson with a mean of at most T, the global
        // majorant's optical depth over the range (a residual rate is at most
        // the majorant, as 0 <= L <= c <= M); T + 10 sqrt(T) + 64 is
        // exceeded with probability below 1e-20
        // (rate_factor: sample_t_maj's, every rate times it)
        Float T = (k.max_majorant * rate_factor + f.extra) * len;
        f.max_collisions = to_bound(T + 10.f * dr::sqrt(T) + 64.f);
        return f;
    }

    /**
     * Moves every living flight to its next tentative collision: consumes
     * tau segment by segment of the walk (tentative collisions come at rate
     * mu = rate(): scale x the segment's bound, or its residual's) until
     * tau < mu x (what is left of the segment), where t becomes the
     * collision; a flight whose walk ends first dies. Residual: adds the
     * control's optical depth over the distance covered. One loop of walk
     * steps only, so that the lookups that follow run for all lanes of a
     * packet at once.
     */
    static void next_collision(const TrackedMedium &k, const WalkRay &wr, Flight &flight,
                               bool residual, bool with_extra = false) {
        flight.searching = flight.alive;
        dr::tie(flight) = dr::while_loop(
            dr::make_tuple(flight), [](const Flight &f) { return f.searching; },
            [k, wr, residual, with_extra](Flight &f) {
                auto [mu, c] = rate(k, f.walk, residual, with_extra ? &f.extra : nullptr);
                Float end = f.walk.segment_end(), t = dr::maximum(f.t, f.walk.segment_begin()),
                      depth = mu * (end - t);
                Mask found = f.searching && (f.tau < depth), miss = f.searching && !found;
                if (residual)
                    dr::masked(f.control_depth, f.searching) +=
                        c * (dr::select(found, f.tau / mu, end - t));
                f.t = dr::select(found, t + f.tau / mu, f.t);
                f.searching &= !found;
                dr::masked(f.tau, miss) = f.tau - depth;
                dr::masked(f.t, miss) = end;
                Mask more = k.volume->walk_advance(f.walk, wr, miss, residual);
                f.alive &= !(miss && !more);
                f.searching &= more;
                // The loop bound: a stopped walk ends the flight (no collision)
                dr::masked(f.steps, miss) += 1;
                Mask trip = f.searching && f.steps > f.max_steps;
                dr::masked(f.tripped, trip) |= (1u << WalkLoop);
                f.alive &= !trip;
                f.searching &= !trip;
            },
            "volpathlocal: walk to the next collision");
    }

    /// A uniform number from the flight's random source: a Mitsuba
    /// sampler, or any DRJIT_STRUCT with next_1d(mask) (walk_bridge.cpp's
    /// PCG32, whose state a Python integrator's sampler seeds)
    static Float draw(Sampler *sampler, const Mask &active) { return sampler->next_1d(active); }
    template <typename Source> static Float draw(Source &source, const Mask &active) {
        return source.next_1d(active);
    }

    /**
     * pbrt-v4's SampleT_maj over the walk: the tentative collisions along
     * `ray` in medium k up to tmax. At each, collide(state, flight, mu, c,
     * sampler, active) (flight.t the collision, mu and c the segment's
     * rate(): mu = scale x the segment's bound and c = 0, or with
     * `residual` its residual's bound and control) updates the estimator's state and
     * returns the lanes that go on; those draw a new tau. `loop` names the
     * estimator's loop (its bound). Returns the flight, ended: its walk ran
     * out, or collide stopped it. `sampler`: a Sampler *, or another random
     * source (draw()). `rate_factor` (>= 1; walk_bridge.cpp's headroom)
     * multiplies every rate: tau is drawn against the walk's rate times
     * it, and collide gets mu times it.
     */
    template <typename State, typename Collide, typename Source = Sampler *>
    static Flight sample_t_maj(const TrackedMedium &k, const WalkRay &wr, const Float &mint,
                               const Float &maxt, Source sampler, State &state,
                               LoopBound loop, const Mask &active, Collide &&collide,
                               const char *label, bool residual = false,
                               const Float *extra = nullptr, float rate_factor = 1.f) {
        struct Loop {
            Flight flight;
            State state;
            Source sampler;
            DRJIT_STRUCT(Loop, flight, state, sampler)
        } ls = { begin_flight(k, wr, mint, maxt,
                              -dr::log(1.f - draw(sampler, active)) / rate_factor, active,
                              residual, extra, rate_factor),
                 state, sampler };
        const bool with_extra = extra != nullptr;
        dr::tie(ls) = dr::while_loop(
            dr::make_tuple(ls), [](const Loop &ls) { return ls.flight.alive; },
            [k, wr, loop, collide, residual, with_extra, rate_factor](Loop &ls) {
                next_collision(k, wr, ls.flight, residual, with_extra);
                Mask hit = ls.flight.alive;
                if (dr::none_or<false>(hit))
                    return; // (scalar: the walk ended)
                auto [mu, c] = rate(k, ls.flight.walk, residual,
                                    with_extra ? &ls.flight.extra : nullptr);
                if (rate_factor != 1.f)
                    mu *= rate_factor;
                Mask more = collide(ls.state, ls.flight, mu, c, ls.sampler, hit);
                dr::masked(ls.flight.tau, hit && more) =
                    -dr::log(1.f - draw(ls.sampler, hit && more)) / rate_factor;
                ls.flight.alive &= !(hit && !more);
                // The loop bound: past it the flight ends here, as if the
                // walk had ended
                dr::masked(ls.flight.collisions, hit) += 1;
                Mask trip = hit && ls.flight.alive &&
                            ls.flight.collisions > ls.flight.max_collisions;
                dr::masked(ls.flight.tripped, trip) |= (1u << loop);
                ls.flight.alive &= !trip;
            },
            label);
        state = ls.state;
        return ls.flight;
    }

    /// The first real collision of delta tracking, and the path's factor
    struct Collision {
        Mask real;                    ///< a real collision at mei (else none before tmax)
        MediumInteraction3f mei;
        UnpolarizedSpectrum weight;   ///< the path throughput's factor (every lane)
        UnpolarizedSpectrum emitted;  ///< the emission met on the way, to add to the
                                      ///< path's radiance times its throughput
        UInt32 tripped;               ///< loop bounds that stopped the flight (bits)
    };

    /**
     * Delta tracking along `ray` through tracked medium k up to tmax (the
     * nearest surface). A tentative collision at t is real with probability
     * P = mean(mu_t(t)) / mu, null otherwise; the path's weight is the
     * product over the null collisions of (mu - mu_t) / (mu (1 - P)) (1 for
     * a grey extinction), times mu_s / mean(mu_t) at the real one (a path
     * that meets no real collision keeps the product of the null factors):
     * volpath's estimator, with the local majorant mu.
     *
     * Emission (an emissive medium, k.emissive): pbrt-v4's estimator, at
     * every tentative collision, real or null, before it is resolved, adds
     *     W x sigma_a(t) Le(t) / mu,   sigma_a = sigma_t - sigma_s,
     * W the product of the null factors before it. Tentative collisions
     * come with density mu(t) exp(-int_0^t mu), and a flight reaches one at
     * t with probability x weight W whose mean is the transmittance T(t)
     * (per channel, ratio tracking's identity), so the sum's mean is
     * int_0^d T(t) sigma_a(t) Le(t) dt, the emission the ray collects. It
     * needs no bound on Le; mu must bound sigma_t (it does). A stochastic
     * lookup's sigma_t is an unbiased estimate independent of Le's lookup,
     * so the product stays unbiased.
     */
    static Collision delta_tracking(const TrackedMedium &k, const Ray3f &ray, const Float &tmax,
                                    const Float &coarse_depth, Sampler *sampler, Mask active,
                                    const EmissionMis &mis) {
        auto [mint, maxt, wr] = span(k, ray, tmax, coarse_depth, active);
        struct State {
            UnpolarizedSpectrum weight, sigma_s, sigma_t, emitted;
            Float majorant;
            Mask real;
            DRJIT_STRUCT(State, weight, sigma_s, sigma_t, emitted, majorant, real)
        } st = { UnpolarizedSpectrum(1.f), dr::zeros<UnpolarizedSpectrum>(),
                 dr::zeros<UnpolarizedSpectrum>(), dr::zeros<UnpolarizedSpectrum>(), Float(0.f),
                 Mask(false) };
        Flight f = sample_t_maj(
            k, wr, mint, maxt, sampler, st, DeltaLoop, active,
            [k, ray, mint, mis](State &s, const Flight &f_, const Float &mu, const Float & /* c */,
                                Sampler *sampler_, const Mask &hit) {
                const Float &t = f_.t;
                Float xi = sampler_->next_1d(hit);
                MediumInteraction3f mei = interaction_at(k, ray, t, mint);
                auto [sigma_s, sigma_n, sigma_t] = coefficients(k, mei, sampler_, hit);
                DRJIT_MARK_USED(sigma_n);
                if (k.emissive) { // (traced only for an emissive medium)
                    Float w = 1.f;
                    if (k.nee) { // (traced only where next-event estimation samples it)
                        Mask on = hit && mis.on;
                        Float p_nee = k.select * k.emissive->emission_point_pdf(mei.p, on) *
                                      dr::squared_norm(mei.p - mis.origin);
                        Float w_mis = mis.nee_only
                            ? Float(0.f)
                            : dr::select(p_nee > 0.f, power_heuristic(mis.dir_pdf, p_nee), 1.f);
                        w = dr::select(on, w_mis, 1.f);
                    }
                    dr::masked(s.emitted, hit) += s.weight * (sigma_t - sigma_s) *
                                                  k.emissive->eval_emission(mei, hit) * w / mu;
                }
                return !decide(s, hit, xi, mu, sigma_s, sigma_t);
            },
            "volpathlocal: delta tracking");
        return collision_of(k, ray, mint, st, f.t, f.tripped);
    }

    /// Delta tracking's choice at a tentative collision of the lanes
    /// `open`: real with probability P = mean(mu_t) / mu (xi uniform), its
    /// coefficients and majorant then kept in the state; null otherwise,
    /// the path's weight times (mu - mu_t) / (mu (1 - P)). Returns the
    /// real lanes
    template <typename S>
    static Mask decide(S &s, const Mask &open, const Float &xi, const Float &mu,
                       const UnpolarizedSpectrum &sigma_s, const UnpolarizedSpectrum &sigma_t) {
        Float p_real = dr::mean(sigma_t) / mu;
        Mask real = open && (xi < p_real), null = open && !real;
        dr::masked(s.weight, null) *= (mu - sigma_t) / (mu * (1.f - p_real));
        dr::masked(s.sigma_s, real) = sigma_s;
        dr::masked(s.sigma_t, real) = sigma_t;
        dr::masked(s.majorant, real) = mu;
        s.real |= real;
        return real;
    }

    /// The Collision of a flight's state: its real collision at t (else
    /// none, the flight having ended at t)
    template <typename S>
    static Collision collision_of(const TrackedMedium &k, const Ray3f &ray, const Float &mint,
                                  const S &st, const Float &t, const UInt32 &tripped) {
        Collision c;
        c.real = st.real;
        c.tripped = tripped;
        c.emitted = st.emitted;
        c.mei = interaction_at(k, ray, dr::select(st.real, t, dr::Infinity<Float>), mint);
        c.mei.p = ray(t);
        c.mei.sigma_s = st.sigma_s;
        c.mei.sigma_t = st.sigma_t;
        c.mei.sigma_n = st.majorant - st.sigma_t;
        c.mei.combined_extinction = st.majorant;
        // The null collisions' factors apply to every path, real collision
        // or not (they are 1 for a grey extinction)
        c.weight = st.weight * dr::select(st.real, st.sigma_s / dr::mean(st.sigma_t),
                                          UnpolarizedSpectrum(1.f));
        return c;
    }

    /**
     * The camera's segment through an emissive medium (issue 35: the fire
     * seen directly): delta tracking's first real collision, as
     * delta_tracking() (the path's weight and vertex), and the emission
     * along the whole segment by ratio tracking, on the same tentative
     * collisions, in one walk. Delta tracking collects the emission only up
     * to its first real collision (its survival past a tentative collision
     * is 0 or 1); here every tentative collision t_i adds
     *     W_i sigma_a(t_i) Le(t_i) / mu,   W_i = prod_{j < i} (mu - mu_t(t_j)) / mu,
     * the survival replaced by its estimate, to the end of the medium. The
     * product over the Poisson points before t is unbiased for T(t) (ratio
     * tracking's identity) and independent of the point at t, so the sum's
     * mean is int T sigma_a Le, delta tracking's, with the survival's
     * variance averaged out. Russian roulette ends W below EMISSION_RR
     * (weighted); the walk goes on while the path has no real collision or
     * W is above 0.
     *
     * `per_voxel` raises the rate of tentative collisions by that many per
     * voxel the ray crosses, where the segment's bound is above 0 (mu is
     * that rate): delta and ratio tracking are unbiased at any rate at or
     * above the majorant, and a higher one samples the emission at more
     * points. On the fireball (emission only, max_depth 1), 0, 0.25 and 1
     * per voxel gave 0.74, 0.15 and 0.066 of the collision estimator's
     * variance; at full depth 1 per voxel takes the fire's pixels from 0.53
     * to 0.21 of its variance (scattering is the rest).
     */
    static constexpr float EMISSION_RR = 0.1f;

    static Collision camera_tracking(const TrackedMedium &k, const Ray3f &ray, const Float &tmax,
                                     const Float &coarse_depth, Sampler *sampler, Mask active,
                                     ScalarFloat per_voxel) {
        auto [mint, maxt, wr] = span(k, ray, tmax, coarse_depth, active);
        // (per voxel: the walk's index-space direction is voxels per unit of t)
        Float extra = per_voxel * dr::norm(wr.direction);
        struct State {
            UnpolarizedSpectrum weight, ratio, sigma_s, sigma_t, emitted;
            Float majorant, t_real;
            Mask real;
            DRJIT_STRUCT(State, weight, ratio, sigma_s, sigma_t, emitted, majorant, t_real, real)
        } st = { UnpolarizedSpectrum(1.f), UnpolarizedSpectrum(1.f),
                 dr::zeros<UnpolarizedSpectrum>(), dr::zeros<UnpolarizedSpectrum>(),
                 dr::zeros<UnpolarizedSpectrum>(), Float(0.f), Float(0.f), Mask(false) };
        Flight f = sample_t_maj(
            k, wr, mint, maxt, sampler, st, DeltaLoop, active,
            [k, ray, mint](State &s, const Flight &f_, const Float &mu, const Float & /* c */,
                           Sampler *sampler_, const Mask &hit) {
                MediumInteraction3f mei = interaction_at(k, ray, f_.t, mint);
                auto [sigma_s, sigma_n, sigma_t] = coefficients(k, mei, sampler_, hit);
                DRJIT_MARK_USED(sigma_n);
                // The emission, by ratio tracking
                dr::masked(s.emitted, hit) += s.ratio * (sigma_t - sigma_s) *
                                              k.emissive->eval_emission(mei, hit) / mu;
                dr::masked(s.ratio, hit) *= (mu - sigma_t) / mu;
                Float w = dr::max(s.ratio);
                Mask low = hit && (w < EMISSION_RR) && (w > 0.f);
                if (dr::any_or<true>(low)) {
                    Float q = w * (1.f / EMISSION_RR);
                    Float xi = sampler_->next_1d(low);
                    dr::masked(s.ratio, low) = dr::select(xi < q, s.ratio / q, 0.f);
                }
                // The path's first real collision, as delta_tracking's
                Mask open = hit && !s.real;
                Float xi = sampler_->next_1d(open);
                Mask real = decide(s, open, xi, mu, sigma_s, sigma_t);
                dr::masked(s.t_real, real) = f_.t;
                return !s.real || !dr::all(s.ratio == 0.f);
            },
            "volpathlocal: the camera's segment", false, per_voxel > 0.f ? &extra : nullptr);
        return collision_of(k, ray, mint, st, dr::select(st.real, st.t_real, f.t), f.tripped);
    }

    /**
     * The transmittance along `ray` through tracked medium k up to tmax,
     * estimated over the tentative collisions (stopping where the estimate
     * reaches 0); returns it and the bounds that tripped.
     *
     * Ratio tracking (residual = false; Cramer 1978, Novak et al. 2014):
     * collisions at rate mu = scale x the segment's bound, the estimate
     * prod (mu - mu_t(t)) / mu. Poisson collisions of rate mu give
     * E[prod f(t_i)] = exp(-int mu (1 - f)), here exp(-int mu_t).
     *
     * Residual ratio tracking (residual = true; Novak, Selle, Jarosz 2014,
     * section 4): with the walk's control c per segment (scale x its cell's
     * mean, majorant_table.h), the estimate
     *     exp(-int c) x prod (mu_r - (mu_t(t) - c)) / mu_r,
     * collisions at the residual's rate mu_r = max(M - c, c - L) (rate()):
     * by the same identity, the product's mean is exp(-int (mu_t - c)), so
     * the whole is unbiased for any c, and each factor lies in [0, 2]
     * where L <= mu_t <= M. The control's part is exact; only the residual
     * is sampled: chosen over ratio tracking, a minorant control and
     * ray marching by a model on real shadow rays (bench/results/
     * transmittance_estimators.md, docs/research/issue34_variance.md):
     * 2.5x (smoke) and 4.7-5x (a generated cloud) the efficiency, with
     * fewer lookups. A stochastic filter's lookup is an unbiased estimate
     * of mu_t, independent per collision, and the factor is linear in it,
     * so the estimate stays unbiased. Russian roulette ends an estimate
     * that has fallen below RESIDUAL_RR (it adds at most RESIDUAL_RR x T
     * to the estimate's second moment): without it, a flight goes on to
     * the end of the ray, where ratio tracking often stops at a weight of
     * 0. The threshold was chosen on the image's variance x time
     * (bench/variance_split.py, PERF_LOG section 41): 1e-3, 0.02, 0.1,
     * 0.3 and 1 gave 1.04, 1.01, 0.92, 0.88 and 1.05 of ratio tracking's
     * on the smoke, 1.00, 0.89, 0.96, 0.90, 1.09 on a generated cloud.
     *
     * estimates > 1: the mean of that many independent estimates (a
     * measurement of the shadow rays' share of the variance:
     * volpathlocal's shadow_estimates)
     */
    /// Residual ratio tracking's Russian roulette threshold (see ratio_tracking)
    static constexpr float RESIDUAL_RR = 0.3f;

    static std::pair<UnpolarizedSpectrum, UInt32>
    ratio_tracking(const TrackedMedium &k, const Ray3f &ray, const Float &tmax,
                   const Float &coarse_depth, Sampler *sampler, Mask active,
                   uint32_t estimates = 1, bool residual = false) {
        auto [mint, maxt, wr] = span(k, ray, tmax, coarse_depth, active);
        auto one = [&](Sampler *sampler_, const Mask &active_) {
            UnpolarizedSpectrum tr(1.f);
            Flight f = sample_t_maj(
                k, wr, mint, maxt, sampler_, tr, RatioLoop, active_,
                [k, ray, mint, residual](UnpolarizedSpectrum &tr_, const Flight &f_,
                                         const Float &mu, const Float &c, Sampler *s,
                                         const Mask &hit) {
                    auto [sigma_s, sigma_n, sigma_t] =
                        coefficients(k, interaction_at(k, ray, f_.t, mint), s, hit);
                    DRJIT_MARK_USED(sigma_s);
                    DRJIT_MARK_USED(sigma_n);
                    if (!residual) {
                        dr::masked(tr_, hit) *= (mu - sigma_t) / mu;
                        return !dr::all(tr_ == 0.f);
                    }
                    dr::masked(tr_, hit) *= (mu - (sigma_t - c)) / mu;
                    // Russian roulette on the estimate so far, tr x exp(-the
                    // controls' depth so far): below RESIDUAL_RR it goes on
                    // with probability estimate / RESIDUAL_RR, divided by it.
                    // Unbiased; it ends flights that have little left to
                    // carry, and those whose control alone has absorbed
                    // them (a dense cell whose ring reaches empty space has
                    // L = 0, and so a rate of c: without it, a density of
                    // 1e6 would take ~1e6 collisions per unit of length,
                    // where ratio tracking stops at its first)
                    Float w = dr::max(tr_) * dr::exp(-f_.control_depth);
                    Mask low = hit && (w < RESIDUAL_RR);
                    if (dr::any_or<true>(low)) {
                        Float q = w * (1.f / RESIDUAL_RR);
                        Float xi = s->next_1d(low);
                        dr::masked(tr_, low) = dr::select(xi < q, tr_ / q, 0.f);
                    }
                    return !dr::all(tr_ == 0.f);
                },
                residual ? "volpathlocal: residual ratio tracking" : "volpathlocal: ratio tracking",
                residual);
            if (residual)
                tr *= dr::exp(-f.control_depth);
            return std::make_pair(tr, f.tripped);
        };
        if (estimates == 1)
            return one(sampler, active);
        struct Mean {
            UnpolarizedSpectrum sum;
            UInt32 tripped, i;
            Sampler *sampler;
            DRJIT_STRUCT(Mean, sum, tripped, i, sampler)
        } m = { dr::zeros<UnpolarizedSpectrum>(), UInt32(0), UInt32(0), sampler };
        const uint32_t n = estimates;
        dr::tie(m) = dr::while_loop(
            dr::make_tuple(m), [n, active](const Mean &m) { return active && m.i < n; },
            [one, n, active](Mean &m) {
                Mask go = active && m.i < n;
                auto [tr, tripped] = one(m.sampler, go);
                dr::masked(m.sum, go) += tr;
                dr::masked(m.tripped, go) |= tripped;
                m.i += 1;
            },
            "volpathlocal: shadow estimates");
        return { m.sum / float(n), m.tripped };
    }
};

NAMESPACE_END(mitsuba)
