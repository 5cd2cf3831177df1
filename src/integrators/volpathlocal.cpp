#include <mitsuba/core/properties.h>
#include <mitsuba/core/ray.h>
#include <mitsuba/render/bsdf.h>
#include <mitsuba/render/emitter.h>
#include <mitsuba/render/integrator.h>
#include <mitsuba/render/medium.h>
#include <mitsuba/render/phase.h>
#include <mitsuba/render/records.h>
#include <mitsuba/render/scene.h>
#include <mitsuba/render/sensor.h>
#include <mitsuba/render/shape.h>

#include <nanovdb_mitsuba/local_majorants.h>
#include <nanovdb_mitsuba/plugin_variants.h>

#include <atomic>
#include <mutex>
#include <typeinfo>
#include <vector>

NAMESPACE_BEGIN(mitsuba)

/**!

.. _integrator-volpathlocal:

Volumetric path tracer with local majorants (:monosp:`volpathlocal`)
--------------------------------------------------------------------

.. pluginparameters::

 * - max_depth
   - |int|
   - Specifies the longest path depth in the generated output image (where
     -1 corresponds to :math:`\infty`). A value of 1 will only render directly
     visible light sources. 2 will lead to single-bounce (direct-only)
     illumination, and so on. (Default: -1)

 * - rr_depth
   - |int|
   - Specifies the minimum path depth, after which the implementation will
     start to use the *russian roulette* path termination criterion.
     (Default: 5)

 * - hide_emitters
   - |bool|
   - Hide directly visible emitters. (Default: no, i.e. |false|)

 * - max_majorant_ratio
   - |float|
   - A ``nanovdbvolume`` medium is tracked through its local majorants only
     if they average at most this fraction of its global majorant over the
     volume (its ``to_string()`` shows the fraction as
     ``local_majorant_ratio``: 0.06 for a real smoke, 1 for a cube of one
     density). Above it the walk would cost its steps and save too few
     null collisions, and the medium is tracked as ``volpath`` does.
     (Default: 0.5: measured, the benchmark cloud at 0.31 renders 0.64x as
     long through the walk, a fog sphere at 0.60 1.14x)

 * - coarse_optical_depth
   - |float|
   - Nodes of a NanoVDB tree (lower and upper internal nodes) whose majorant
     gives at most this optical depth along any chord through them are
     crossed as one segment with that majorant instead of node by node: a
     few null collisions there cost less than the steps of the walk.
     ``0`` walks every leaf. (Default: 2)

A drop-in replacement for :ref:`volpath <integrator-volpath>` that renders
``heterogeneous`` media whose ``sigma_t`` is a ``nanovdbvolume`` several
times faster. The stock medium samples free-flight distances against one
global majorant (``scale * max()``), so every null collision costs a lookup
wherever the medium is thin or empty. Here a ray is walked through the
NanoVDB tree node by node (leaf, tile, thin internal node), each with its
own majorant computed at load time, and:

- free-flight distances of camera and scattered paths are sampled by delta
  tracking against that piecewise constant majorant, up to the nearest
  surface;
- shadow rays estimate transmittance by ratio tracking against it.

Empty space costs one step per node and no lookup. Every other medium
(homogeneous, ``gridvolume``-based, ...) takes the same code path as in
``volpath``, through the medium's own ``sample_interaction``, so every scene
that ``volpath`` renders renders here, with the same expected value: surfaces
inside media, media inside dielectrics, nested media, emitter sampling with
multiple importance sampling, RGB, spectral, monochrome and polarized
variants.

The estimators (for a tracked medium, with majorant :math:`\bar\mu(t)` =
``scale`` times the node's bound, extinction :math:`\mu_t`, scattering
:math:`\mu_s`, null :math:`\mu_n = \bar\mu - \mu_t`, per channel):

- delta tracking: tentative collisions are sampled with density
  :math:`\bar\mu(t) \exp(-\int \bar\mu)`; each is real with probability
  :math:`P_r = \mathrm{mean}(\mu_t) / \bar\mu`, weight
  :math:`\mu_s / \mathrm{mean}(\mu_t)`, and null otherwise, weight
  :math:`\mu_n / \mathrm{mean}(\mu_n)` (1 for a grey extinction);
- ratio tracking: the transmittance estimate is
  :math:`\prod \mu_n / \bar\mu` over the tentative collisions.

.. tabs::
    .. code-tab:: xml

        <integrator type="volpathlocal">
            <integer name="max_depth" value="64"/>
        </integrator>

    .. code-tab:: python

        'type': 'volpathlocal',
        'max_depth': 64

*/
template <typename Float, typename Spectrum>
class VolumetricPathLocalMajorants final : public MonteCarloIntegrator<Float, Spectrum> {
public:
    MI_IMPORT_BASE(MonteCarloIntegrator, m_max_depth, m_rr_depth, m_hide_emitters)
    MI_IMPORT_TYPES(Scene, Sampler, Sensor, Emitter, EmitterPtr, BSDF, BSDFPtr, Medium,
                    MediumPtr, PhaseFunctionContext)
    using Majorants = LocalMajorants<Float, Spectrum>;
    using Walk = typename Majorants::Walk;
    using WalkRay = typename Majorants::WalkRay;

    VolumetricPathLocalMajorants(const Properties &props) : Base(props) {
        m_coarse_depth = props.get<ScalarFloat>("coarse_optical_depth", 2.f);
        if (!(m_coarse_depth >= 0.f) || !std::isfinite(m_coarse_depth))
            Throw("volpathlocal: coarse_optical_depth must be a finite value >= 0, got %f",
                  m_coarse_depth);
        m_max_ratio = props.get<ScalarFloat>("max_majorant_ratio", 0.5f);
        if (!(m_max_ratio >= 0.f && m_max_ratio <= 1.f))
            Throw("volpathlocal: max_majorant_ratio must be in [0, 1], got %f", m_max_ratio);
        if constexpr (dr::is_jit_v<Float>)
            m_trips = dr::zeros<UInt32>(LoopCount);
    }

    TensorXf render(Scene *scene, Sensor *sensor, UInt32 seed = 0, uint32_t spp = 0,
                    bool develop = true, bool evaluate = true) override {
        if (trip_counts_ready()) // trips of earlier renders not reported yet
            report_trips();
        prepare(scene, true);
        TensorXf image = Base::render(scene, sensor, seed, spp, develop, evaluate);
        // (a JIT image not evaluated yet: its trips are reported by the next
        // render(), to_string() or traverse(), so as not to evaluate it here)
        if ((evaluate && !recording()) || trip_counts_ready())
            report_trips();
        return image;
    }

    void traverse(TraversalCallback *cb) override {
        Base::traverse(cb);
        // How many lanes the loop bounds stopped so far (see LoopBound; per
        // loop in to_string()): 0 unless something is wrong
        m_trip_total_host = 0;
        for (uint32_t n : trip_counts())
            m_trip_total_host += n;
        cb->put("loop_bound_trips", m_trip_total_host, ParamFlags::NonDifferentiable);
    }

    // =====================================================================
    //  The path: volpath's, with tracked media sampled through the walk
    // =====================================================================

    std::pair<Spectrum, Mask> sample(const Scene *scene, Sampler *sampler,
                                     const RayDifferential3f &ray_,
                                     const Medium *initial_medium, Float * /* aovs */,
                                     Mask active) const override {
        MI_MASKED_FUNCTION(ProfilerPhase::SamplingIntegratorSample, active);
        prepare(scene, false);

        // With a visible environment emitter every ray is valid; otherwise a
        // ray is valid once it scatters
        Mask valid_ray = !m_hide_emitters && (scene->environment() != nullptr);

        UInt32 channel = 0;
        if constexpr (is_rgb_v<Spectrum>) {
            uint32_t n_channels = (uint32_t) dr::size_v<Spectrum>;
            channel = (UInt32) dr::minimum(sampler->next_1d(active) * n_channels, n_channels - 1);
        }

        struct PathState {
            Mask active;
            UInt32 depth;
            Ray3f ray;
            Spectrum throughput, result;
            SurfaceInteraction3f si;
            MediumInteraction3f mei;
            MediumPtr medium;
            Float eta;                        ///< radiance scaling by refraction
            Interaction3f last_scatter_event;
            Float last_scatter_direction_pdf;
            Mask needs_intersection, specular_chain, valid_ray;
            UInt32 stalls, steps; ///< the loop bound (see LoopBound)
            UInt32 tripped;       ///< bit i: loop bound i stopped this path
            Sampler *sampler;
            DRJIT_STRUCT(PathState, active, depth, ray, throughput, result, si, mei, medium, eta,
                         last_scatter_event, last_scatter_direction_pdf, needs_intersection,
                         specular_chain, valid_ray, stalls, steps, tripped, sampler)
        } ps = { active,
                 UInt32(0),
                 Ray3f(ray_),
                 Spectrum(1.f),
                 Spectrum(0.f),
                 dr::zeros<SurfaceInteraction3f>(),
                 dr::zeros<MediumInteraction3f>(),
                 MediumPtr(initial_medium),
                 Float(1.f),
                 dr::zeros<Interaction3f>(),
                 Float(1.f),
                 Mask(true),
                 Mask(active && !m_hide_emitters),
                 valid_ray,
                 UInt32(0),
                 UInt32(0),
                 UInt32(0),
                 sampler };

        dr::tie(ps) = dr::while_loop(
            dr::make_tuple(ps), [](const PathState &ps) { return ps.active; },
            [this, scene, channel](PathState &ps) {
                Ray3f before = ps.ray;
                UInt32 depth_before = ps.depth;
                path_step(scene, channel, ps);
                Mask moved = ps.depth != depth_before || dr::any(ps.ray.o != before.o) ||
                             dr::any(ps.ray.d != before.d);
                bound_loop(PathLoop, moved, ps.active, ps.stalls, ps.steps, ps.tripped);
            },
            "volpathlocal: path");
        record_trips(ps.tripped, active);
        return { ps.result, ps.valid_ray };
    }

    std::string to_string() const override {
        report_trips();
        std::vector<uint32_t> trips = trip_counts();
        std::string trip_list;
        for (uint32_t i = 0; i < LoopCount; ++i)
            trip_list += tfm::format("%s%s: %u", i ? ", " : "", kLoopNames[i], trips[i]);
        return tfm::format("VolumetricPathLocalMajorants[\n"
                           "  max_depth = %i,\n"
                           "  rr_depth = %i,\n"
                           "  coarse_optical_depth = %f,\n"
                           "  max_majorant_ratio = %f,\n"
                           "  tracked media = %zu,\n"
                           "  loop bound trips = [%s]\n"
                           "]",
                           m_max_depth, m_rr_depth, m_coarse_depth, m_max_ratio,
                           m_tracked.size(), trip_list);
    }

    MI_DECLARE_CLASS(VolumetricPathLocalMajorants)

private:
    /**
     * Each loop of this integrator stops a lane after more iterations than a
     * valid ray can take, and counts it; render() warns, and to_string() and
     * traverse() ("loop_bound_trips") show the counts. A trip means a bug or
     * an input outside what the integrator supports; the lane then ends as
     * if it had left the medium (or the path had been absorbed), so the
     * image is finite but biased there.
     *  - path, shadow ray: kMaxStalls iterations in a row in which the path
     *    neither scattered nor moved (every valid iteration does one of the
     *    two, or ends the path), or kMaxLoopSteps in all;
     *  - walk: a flight's steps beyond twice the cell faces its segment can
     *    cross (begin_flight());
     *  - delta, ratio tracking: tentative collisions beyond the Poisson tail
     *    of the global majorant's optical depth (begin_flight()).
     */
    enum LoopBound : uint32_t { PathLoop = 0, ShadowLoop, WalkLoop, DeltaLoop, RatioLoop,
                                LoopCount };
    static constexpr const char *kLoopNames[LoopCount] = { "path", "shadow ray", "walk",
                                                           "delta tracking", "ratio tracking" };
    static constexpr uint32_t kMaxStalls = 16;
    static constexpr uint32_t kMaxLoopSteps = 1u << 24;

    /// A heterogeneous medium whose sigma_t offers local majorants
    struct Tracked {
        const Medium *medium;
        const Majorants *volume;
        ScalarFloat scale;
        ScalarFloat max_majorant; ///< scale x the largest segment bound
    };

    /// Reads a medium's "sigma_t" and "scale" (what heterogeneous exposes)
    struct FindParameters final : public TraversalCallback {
        Object *sigma_t = nullptr;
        ScalarFloat scale = 1.f;
        bool has_scale = false;
        void put_value(std::string_view name, void *value, uint32_t,
                       const std::type_info &type) override {
            if (name == "scale" && type == typeid(ScalarFloat)) {
                scale = *static_cast<const ScalarFloat *>(value);
                has_scale = true;
            }
        }
        void put_object(std::string_view name, Object *value, uint32_t) override {
            if (name == "sigma_t")
                sigma_t = value;
        }
    };

    /// Finds the media to track: every `heterogeneous` medium of the scene
    /// (on shapes, sensors, emitters) whose sigma_t offers local majorants.
    /// Done on every render (a scale may have changed), and on the first
    /// sample() for a scene that render() did not see.
    void prepare(const Scene *scene, bool force) const {
        if (!force && m_prepared_for.load(std::memory_order_acquire) == scene)
            return; // the common case: no lock per sample() call
        std::lock_guard<std::mutex> guard(m_prepare_mutex);
        if (!force && m_prepared_for.load(std::memory_order_relaxed) == scene)
            return;
        std::vector<const Medium *> media;
        auto add = [&](const Medium *m) {
            if (m && std::find(media.begin(), media.end(), m) == media.end())
                media.push_back(m);
        };
        for (const auto &shape : scene->shapes()) {
            add(shape->interior_medium());
            add(shape->exterior_medium());
        }
        for (const auto &sensor : scene->sensors())
            add(sensor->medium());
        for (const auto &emitter : scene->emitters())
            add(emitter->medium());
        std::vector<Tracked> tracked;
        for (const Medium *m : media) {
            if (m->class_name() != std::string_view("HeterogeneousMedium"))
                continue;
            FindParameters p;
            const_cast<Medium *>(m)->traverse(&p);
            const Majorants *v = p.sigma_t ? dynamic_cast<const Majorants *>(p.sigma_t) : nullptr;
            // (scale 0: nothing to track, and no collision either way)
            if (!v || !p.has_scale || !(p.scale > 0.f))
                continue;
            // A volume of (nearly) one density: the walk would cost its steps
            // and save no null collisions; track it as volpath does
            if (v->local_majorant_ratio() > m_max_ratio) {
                Log(Debug, "volpathlocal: local majorants average %.2f of the global one "
                           "(above max_majorant_ratio = %.2f): tracked as volpath does",
                    v->local_majorant_ratio(), m_max_ratio);
                continue;
            }
            tracked.push_back({ m, v, p.scale, p.scale * v->majorant_bound() });
        }
        Log(Debug, "volpathlocal: %zu of %zu media tracked through local majorants",
            tracked.size(), media.size());
        m_tracked = std::move(tracked);
        m_prepared_for.store(scene, std::memory_order_release);
    }

    /// One iteration of the path loop: a free flight (in a medium) or a
    /// surface interaction, as volpath does; tracked media resolve their
    /// null collisions inside track_collision()
    template <typename PathState>
    void path_step(const Scene *scene, const UInt32 &channel, PathState &ps) const {
        Mask &active = ps.active;
        Sampler *sampler = ps.sampler;
        Ray3f &ray = ps.ray;
        SurfaceInteraction3f &si = ps.si;
        MediumInteraction3f &mei = ps.mei;

        // ----------------- Russian roulette and depth --------------------
        active &= dr::any(unpolarized_spectrum(ps.throughput) != 0.f);
        Float q = dr::minimum(dr::max(unpolarized_spectrum(ps.throughput)) * dr::square(ps.eta),
                              .95f);
        Mask perform_rr = ps.depth > (uint32_t) m_rr_depth;
        active &= sampler->next_1d(active) < q || !perform_rr;
        dr::masked(ps.throughput, perform_rr) *= dr::rcp(dr::detach(q));
        active &= ps.depth < (uint32_t) m_max_depth;
        if (dr::none_or<false>(active))
            return;

        // ----------------------- Free flight ------------------------------
        Mask active_medium = active && (ps.medium != nullptr);
        Mask active_surface = active && !active_medium;
        Mask act_null_scatter = false, act_medium_scatter = false, escaped_medium = false;
        Mask fallback_spectral = false, fallback_grey = false;

        if (dr::any_or<true>(active_medium)) {
            // The nearest surface first: tracking stops there
            Mask intersect = ps.needs_intersection && active_medium;
            if (dr::any_or<true>(intersect))
                dr::masked(si, intersect) = scene->ray_intersect(ray, intersect);
            ps.needs_intersection &= !active_medium;

            Mask tracked = false;
            for (const Tracked &k : m_tracked) {
                Mask in_k = active_medium && (ps.medium == MediumPtr(k.medium));
                if (dr::none_or<false>(in_k))
                    continue; // (scalar variants: not this medium)
                tracked |= in_k;
                auto [real, mei_k, weight, tripped] = track_collision(k, ray, si.t, sampler, in_k);
                ps.tripped |= tripped;
                dr::masked(mei, in_k) = mei_k;
                dr::masked(ps.throughput, real) *= weight;
                act_medium_scatter |= real;
                escaped_medium |= in_k && !real;
            }

            // Every other medium: one tentative collision of its own, as volpath
            Mask other = active_medium && !tracked;
            if (dr::any_or<true>(other)) {
                MediumPtr medium = ps.medium;
                fallback_spectral = other && medium->has_spectral_extinction();
                fallback_grey = other && !fallback_spectral;
                MediumInteraction3f mei_o =
                    medium->sample_interaction(ray, sampler->next_1d(other), channel, other);
                dr::masked(mei_o.t, other && (si.t < mei_o.t)) = dr::Infinity<Float>;
                // Differs from volpath: a flight that leaves the medium without
                // a collision and meets no surface (an unenclosed medium) keeps
                // its throughput, its weight tr / pdf being 1 in the limit;
                // volpath computes 0 / 0 there and loses the path. (Tracked
                // media do the same: see track_collision.)
                Mask weighted = fallback_spectral && (mei_o.is_valid() || si.is_valid());
                if (dr::any_or<true>(weighted)) {
                    auto [tr, free_flight_pdf] =
                        medium->transmittance_eval_pdf(mei_o, si, weighted);
                    Float tr_pdf = index_spectrum(free_flight_pdf, channel);
                    dr::masked(ps.throughput, weighted) *=
                        dr::select(tr_pdf > 0.f, tr / tr_pdf, 0.f);
                }
                escaped_medium |= other && !mei_o.is_valid();
                Mask collided = other && mei_o.is_valid();
                Float null_prob = dr::mean(mei_o.sigma_n / mei_o.combined_extinction);
                Mask null_scatter = collided && sampler->next_1d(collided) < null_prob;
                act_null_scatter |= null_scatter;
                act_medium_scatter |= collided && !null_scatter;
                if (dr::any_or<true>(fallback_spectral && null_scatter))
                    dr::masked(ps.throughput, fallback_spectral && null_scatter) *=
                        mei_o.sigma_n / null_prob;
                Mask real_spectral = fallback_spectral && collided && !null_scatter,
                     real_grey = fallback_grey && collided && !null_scatter;
                dr::masked(ps.throughput, real_spectral) *=
                    mei_o.sigma_s / dr::mean(mei_o.sigma_t / mei_o.combined_extinction);
                dr::masked(ps.throughput, real_grey) *= mei_o.sigma_s / mei_o.sigma_t;
                dr::masked(mei, other) = mei_o;
            }
            // volpath: a lane that left its medium is done with it (without
            // this, a lane whose ray starts outside its medium's box and meets
            // no surface would stay active, unchanged, for ever)
            active_medium &= !escaped_medium;
            dr::masked(ps.depth, act_medium_scatter) += 1;
            dr::masked(ps.last_scatter_event, act_medium_scatter) = mei;
        }

        // No lighting past the maximum depth
        active &= ps.depth < (uint32_t) m_max_depth;
        act_medium_scatter &= active;

        if (dr::any_or<true>(act_null_scatter)) {
            dr::masked(ray.o, act_null_scatter) = mei.p;
            dr::masked(si.t, act_null_scatter) = si.t - mei.t;
        }

        // ----------------------- Medium scattering ------------------------
        if (dr::any_or<true>(act_medium_scatter)) {
            PhaseFunctionContext phase_ctx(sampler);
            auto phase = mei.medium->phase_function();

            Mask sample_emitters = mei.medium->use_emitter_sampling();
            ps.valid_ray |= act_medium_scatter;
            ps.specular_chain &= !act_medium_scatter;
            ps.specular_chain |= act_medium_scatter && !sample_emitters;

            Mask active_e = act_medium_scatter && sample_emitters;
            if (dr::any_or<true>(active_e)) {
                auto [emitted, ds] = sample_emitter(mei, scene, sampler, ps.medium, channel,
                                                    ps.tripped, active_e);
                auto [phase_val, phase_pdf] = phase->eval_pdf(phase_ctx, mei, ds.d, active_e);
                dr::masked(ps.result, active_e) +=
                    ps.throughput * phase_val * emitted *
                    mis_weight(ds.pdf, dr::select(ds.delta, 0.f, phase_pdf));
            }

            dr::masked(phase, !act_medium_scatter) = nullptr;
            auto [wo, phase_weight, phase_pdf] =
                phase->sample(phase_ctx, mei, sampler->next_1d(act_medium_scatter),
                              sampler->next_2d(act_medium_scatter), act_medium_scatter);
            act_medium_scatter &= phase_pdf > 0.f;
            dr::masked(ray, act_medium_scatter) = mei.spawn_ray(wo);
            ps.needs_intersection |= act_medium_scatter;
            dr::masked(ps.last_scatter_direction_pdf, act_medium_scatter) = phase_pdf;
            dr::masked(ps.throughput, act_medium_scatter) *= phase_weight;
        }

        // ---------------------- Surface interactions ----------------------
        active_surface |= escaped_medium;
        Mask intersect = active_surface && ps.needs_intersection;
        if (dr::any_or<true>(intersect))
            dr::masked(si, intersect) = scene->ray_intersect(ray, intersect);

        if (dr::any_or<true>(active_surface)) {
            // Hidden area emitters on the camera ray: skip them
            if (m_hide_emitters && dr::any_or<true>(ps.depth == 0u)) {
                Mask skip = si.is_valid() && (si.shape->emitter() != nullptr) &&
                            (ps.depth == 0u) && intersect;
                if (dr::any_or<true>(skip)) {
                    Ray3f skip_ray = si.spawn_ray(ray.d);
                    PreliminaryIntersection3f pi =
                        Base::skip_area_emitters(scene, skip_ray, true, skip);
                    dr::masked(si, skip) =
                        pi.compute_surface_interaction(skip_ray, +RayFlags::All, skip);
                }
            }

            // Emitters hit: direct, or weighted against emitter sampling
            Mask count_direct = (active_surface && ps.depth == 0u) || ps.specular_chain;
            EmitterPtr emitter = si.emitter(scene);
            Mask active_e = active_surface && (emitter != nullptr) &&
                            !((ps.depth == 0u) && m_hide_emitters);
            if (dr::any_or<true>(active_e)) {
                Float emitter_pdf = 1.f;
                if (dr::any_or<true>(active_e && !count_direct)) {
                    DirectionSample3f ds(scene, si, ps.last_scatter_event);
                    emitter_pdf =
                        scene->pdf_emitter_direction(ps.last_scatter_event, ds, active_e);
                }
                Spectrum emitted = emitter->eval(si, active_e);
                dr::masked(ps.result, active_e) += dr::select(
                    count_direct, ps.throughput * emitted,
                    ps.throughput * mis_weight(ps.last_scatter_direction_pdf, emitter_pdf) *
                        emitted);
            }
        }
        active_surface &= si.is_valid();
        if (dr::any_or<true>(active_surface)) {
            BSDFContext ctx;
            BSDFPtr bsdf = si.bsdf(ray);
            Mask active_e = active_surface && has_flag(bsdf->flags(), BSDFFlags::Smooth) &&
                            (ps.depth + 1 < (uint32_t) m_max_depth);
            if (dr::any_or<true>(active_e)) {
                auto [emitted, ds] = sample_emitter(si, scene, sampler, ps.medium, channel,
                                                    ps.tripped, active_e);
                Vector3f wo = si.to_local(ds.d);
                Spectrum bsdf_val = bsdf->eval(ctx, si, wo, active_e);
                bsdf_val = si.to_world_mueller(bsdf_val, -wo, si.wi);
                Float bsdf_pdf = bsdf->pdf(ctx, si, wo, active_e);
                dr::masked(ps.result, active_e) +=
                    ps.throughput * bsdf_val *
                    mis_weight(ds.pdf, dr::select(ds.delta, 0.f, bsdf_pdf)) * emitted;
            }

            auto [bs, bsdf_val] = bsdf->sample(ctx, si, sampler->next_1d(active_surface),
                                               sampler->next_2d(active_surface), active_surface);
            bsdf_val = si.to_world_mueller(bsdf_val, -bs.wo, si.wi);
            dr::masked(ps.throughput, active_surface) *= bsdf_val;
            dr::masked(ps.eta, active_surface) *= bs.eta;
            dr::masked(ray, active_surface) = si.spawn_ray(si.to_world(bs.wo));
            ps.needs_intersection |= active_surface;

            Mask non_null_bsdf = active_surface && !has_flag(bs.sampled_type, BSDFFlags::Null);
            dr::masked(ps.depth, non_null_bsdf) += 1;
            dr::masked(ps.last_scatter_event, non_null_bsdf) = si;
            dr::masked(ps.last_scatter_direction_pdf, non_null_bsdf) = bs.pdf;

            ps.valid_ray |= non_null_bsdf;
            ps.specular_chain |= non_null_bsdf && has_flag(bs.sampled_type, BSDFFlags::Delta);
            ps.specular_chain &= !(active_surface && has_flag(bs.sampled_type, BSDFFlags::Smooth));
            act_null_scatter |= active_surface && has_flag(bs.sampled_type, BSDFFlags::Null);
            Mask has_medium_trans = active_surface && si.is_medium_transition();
            dr::masked(ps.medium, has_medium_trans) = si.target_medium(ray.d);
        }
        active &= active_surface || active_medium;
    }

    // =====================================================================
    //  Emitter sampling: volpath's shadow ray, tracked media by ratio tracking
    // =====================================================================

    template <typename Interaction>
    std::tuple<Spectrum, DirectionSample3f>
    sample_emitter(const Interaction &ref, const Scene *scene, Sampler *sampler,
                   MediumPtr medium, const UInt32 &channel, UInt32 &tripped, Mask active) const {
        auto [ds, emitter_val] =
            scene->sample_emitter_direction(ref, sampler->next_2d(active), false, active);
        dr::masked(emitter_val, ds.pdf == 0.f) = 0.f;
        active &= ds.pdf != 0.f;
        if (dr::none_or<false>(active))
            return { emitter_val, ds };

        Ray3f ray = ref.spawn_ray_to(ds.p);
        Float max_dist = ray.maxt;
        // Leaving the current medium if ref is on its boundary
        if constexpr (std::is_convertible_v<Interaction, SurfaceInteraction3f>)
            dr::masked(medium, ref.is_medium_transition()) = ref.target_medium(ray.d);

        struct ShadowState {
            Mask active;
            Ray3f ray;
            Float total_dist;
            Mask needs_intersection;
            MediumPtr medium;
            SurfaceInteraction3f si;
            Spectrum transmittance;
            UInt32 stalls, steps, tripped; ///< the loop bound (see LoopBound)
            Sampler *sampler;
            DRJIT_STRUCT(ShadowState, active, ray, total_dist, needs_intersection, medium, si,
                         transmittance, stalls, steps, tripped, sampler)
        } ss = { active, ray, Float(0.f), Mask(true), medium,
                 dr::zeros<SurfaceInteraction3f>(), Spectrum(1.f), UInt32(0), UInt32(0),
                 UInt32(0), sampler };

        dr::tie(ss) = dr::while_loop(
            dr::make_tuple(ss), [](const ShadowState &ss) { return dr::detach(ss.active); },
            [this, scene, channel, max_dist, ds = ds](ShadowState &ss) {
                Point3f before = ss.ray.o;
                shadow_step(scene, channel, max_dist, ds.dist, ss);
                bound_loop(ShadowLoop, dr::any(ss.ray.o != before), ss.active, ss.stalls,
                           ss.steps, ss.tripped);
            },
            "volpathlocal: shadow ray");
        dr::masked(tripped, active) |= ss.tripped;
        return { ss.transmittance * emitter_val, ds };
    }

    template <typename ShadowState>
    void shadow_step(const Scene *scene, const UInt32 &channel, const Float &max_dist,
                     const Float &ds_dist, ShadowState &ss) const {
        Mask &active = ss.active;
        Ray3f &ray = ss.ray;
        SurfaceInteraction3f &si = ss.si;
        Sampler *sampler = ss.sampler;

        Float remaining = max_dist - ss.total_dist;
        ray.maxt = remaining;
        active &= remaining > 0.f;
        if (dr::none_or<false>(active))
            return;

        Mask escaped_medium = false;
        Mask active_medium = active && (ss.medium != nullptr);
        Mask active_surface = active && !active_medium;

        if (dr::any_or<true>(active_medium)) {
            Mask intersect = ss.needs_intersection && active_medium;
            if (dr::any_or<true>(intersect))
                dr::masked(si, intersect) = scene->ray_intersect(ray, intersect);
            ss.needs_intersection &= !active_medium;

            // Tracked media: the whole way to the surface (or the emitter)
            Mask tracked = false;
            for (const Tracked &k : m_tracked) {
                Mask in_k = active_medium && (ss.medium == MediumPtr(k.medium));
                if (dr::none_or<false>(in_k))
                    continue;
                tracked |= in_k;
                auto [tr, tripped] = track_transmittance(k, ray, dr::minimum(si.t, remaining),
                                                         sampler, in_k);
                dr::masked(ss.transmittance, in_k) *= tr;
                ss.tripped |= tripped;
            }
            escaped_medium |= tracked;

            // Every other medium: a tentative collision, as volpath
            Mask other = active_medium && !tracked;
            active_medium = false;
            if (dr::any_or<true>(other)) {
                MediumPtr medium = ss.medium;
                MediumInteraction3f mei =
                    medium->sample_interaction(ray, sampler->next_1d(other), channel, other);
                dr::masked(mei.t, other && (si.t < mei.t)) = dr::Infinity<Float>;
                Mask is_spectral = medium->has_spectral_extinction() && other;
                Mask not_spectral = !is_spectral && other;
                // Differs from volpath, as for the path: no collision and no
                // surface before an emitter at infinity is a weight of 1
                Mask weighted = is_spectral && (mei.is_valid() || si.is_valid());
                if (dr::any_or<true>(weighted)) {
                    Float t = dr::minimum(remaining, dr::minimum(mei.t, si.t)) - mei.mint;
                    UnpolarizedSpectrum tr = dr::exp(-t * mei.combined_extinction);
                    UnpolarizedSpectrum pdf = dr::select(si.t < mei.t || mei.t > remaining, tr,
                                                         tr * mei.combined_extinction);
                    Float tr_pdf = index_spectrum(pdf, channel);
                    dr::masked(ss.transmittance, weighted) *=
                        dr::select(tr_pdf > 0.f, tr / tr_pdf, 0.f);
                }
                // Past the emitter
                dr::masked(ss.total_dist, other && (mei.t > remaining) && mei.is_valid()) =
                    ds_dist;
                dr::masked(mei.t, other && (mei.t > remaining)) = dr::Infinity<Float>;

                escaped_medium |= other && !mei.is_valid();
                active_medium = other && mei.is_valid();
                is_spectral &= active_medium;
                not_spectral &= active_medium;
                dr::masked(ss.total_dist, active_medium) += mei.t;
                if (dr::any_or<true>(active_medium)) {
                    dr::masked(ray.o, active_medium) = mei.p;
                    dr::masked(si.t, active_medium) = si.t - mei.t;
                    dr::masked(ss.transmittance, is_spectral) *= mei.sigma_n;
                    dr::masked(ss.transmittance, not_spectral) *=
                        mei.sigma_n / mei.combined_extinction;
                }
            }
        }

        // Surfaces: null transmission, medium transitions
        Mask intersect = active_surface && ss.needs_intersection;
        if (dr::any_or<true>(intersect))
            dr::masked(si, intersect) = scene->ray_intersect(ray, intersect);
        ss.needs_intersection &= !intersect;
        active_surface |= escaped_medium;
        dr::masked(ss.total_dist, active_surface) += si.t;

        active_surface &= si.is_valid() && active && !active_medium;
        if (dr::any_or<true>(active_surface)) {
            auto bsdf = si.bsdf(ray);
            Spectrum bsdf_val = bsdf->eval_null_transmission(si, active_surface);
            bsdf_val = si.to_world_mueller(bsdf_val, si.wi, si.wi);
            dr::masked(ss.transmittance, active_surface) *= bsdf_val;
        }

        dr::masked(ray, active_surface) = si.spawn_ray(ray.d);
        ray.maxt = remaining;
        ss.needs_intersection |= active_surface;

        active &= (active_medium || active_surface) &&
                  dr::any(unpolarized_spectrum(ss.transmittance) != 0.f);
        Mask has_medium_trans = active_surface && si.is_medium_transition();
        if (dr::any_or<true>(has_medium_trans))
            dr::masked(ss.medium, has_medium_trans) = si.target_medium(ray.d);
    }

    // =====================================================================
    //  Tracking through a tracked medium, segment by segment of the walk
    // =====================================================================

    /// The parameter range of `ray` inside the medium's box, up to tmax
    std::pair<Float, Float> medium_range(const Tracked &k, const Ray3f &ray, const Float &tmax,
                                         Mask &active) const {
        auto [hit, mint, maxt] = k.medium->intersect_aabb(ray);
        mint = dr::maximum(mint, 0.f);
        maxt = dr::minimum(maxt, tmax);
        active &= hit && (mint < maxt);
        return { mint, maxt };
    }

    /// A medium interaction at distance t along the ray, for evaluating the
    /// medium there and scattering from it
    MediumInteraction3f interaction_at(const Tracked &k, const Ray3f &ray, const Float &t,
                                       const Float &mint) const {
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

    struct Collision {
        Mask real;                    ///< a real collision at mei (else none before tmax)
        MediumInteraction3f mei;
        UnpolarizedSpectrum weight;   ///< the path throughput's factor
        UInt32 tripped;               ///< loop bounds that stopped the flight (bits)
    };

    /// A flight through a tracked medium: the walk, the position t along
    /// the ray, and the optical depth tau left to the next tentative collision
    struct Flight {
        Mask alive;     ///< false once the walk has ended (or a real collision)
        Mask searching; ///< inside next_collision(): not yet at a collision
        Walk walk;
        Float t, tau;
        UInt32 steps, collisions;          ///< walk steps, tentative collisions so far
        UInt32 max_steps, max_collisions;  ///< their bounds (see LoopBound)
        UInt32 tripped;                    ///< the bounds that stopped it (bits)
        DRJIT_STRUCT(Flight, alive, searching, walk, t, tau, steps, collisions, max_steps,
                     max_collisions, tripped)
    };

    /// A flight from the start of the medium's range, with a fresh tau
    Flight begin_flight(const Tracked &k, const WalkRay &wr, const Float &mint,
                        const Float &maxt, Sampler *sampler, const Mask &active) const {
        Flight f;
        f.alive = active;
        f.searching = false;
        f.walk = k.volume->walk_begin(wr, mint, maxt, active);
        f.t = mint;
        f.tau = -dr::log(1.f - sampler->next_1d(active));
        f.steps = f.collisions = f.tripped = 0;
        // Walk steps: every step crosses a cell face, and cells are at least
        // 8 voxels wide, so a segment crosses at most sum_a |d_a| len / 8 + 3
        // of them; twice that, and 64 for round-off
        Float len = dr::maximum(maxt - mint, 0.f),
              faces = (dr::abs(wr.direction.x()) + dr::abs(wr.direction.y()) +
                       dr::abs(wr.direction.z())) * len * 0.125f + 3.f;
        f.max_steps = to_bound(2.f * faces + 64.f);
        // Tentative collisions: Poisson with a mean of at most T, the global
        // majorant's optical depth over the range; T + 10 sqrt(T) + 64 is
        // exceeded with probability below 1e-20
        Float T = k.max_majorant * len;
        f.max_collisions = to_bound(T + 10.f * dr::sqrt(T) + 64.f);
        return f;
    }

    /// A float bound as an iteration count (NaN, infinity and >= 2^31: 2^31)
    static UInt32 to_bound(const Float &n) {
        return dr::select(n < 2147483648.f, UInt32(dr::maximum(n, 0.f)), UInt32(1u << 31));
    }

    /**
     * Moves every living flight to its next tentative collision: consumes
     * tau segment by segment of the walk (tentative collisions come at rate
     * mu = scale x the segment's bound) until tau < mu x (what is left of
     * the segment), where t becomes the collision; a flight whose walk ends
     * first dies. One loop of walk steps only, so that the lookups that
     * follow run for all lanes of a packet at once.
     */
    void next_collision(const Tracked &k, const WalkRay &wr, Flight &flight) const {
        flight.searching = flight.alive;
        const ScalarFloat scale = k.scale;
        dr::tie(flight) = dr::while_loop(
            dr::make_tuple(flight), [](const Flight &f) { return f.searching; },
            [k, wr, scale](Flight &f) {
                Float mu = scale * f.walk.majorant, end = f.walk.segment_end(),
                      t = dr::maximum(f.t, f.walk.hdda.tmin), depth = mu * (end - t);
                Mask found = f.searching && (f.tau < depth), miss = f.searching && !found;
                f.t = dr::select(found, t + f.tau / mu, f.t);
                f.searching &= !found;
                dr::masked(f.tau, miss) = f.tau - depth;
                dr::masked(f.t, miss) = end;
                Mask more = k.volume->walk_advance(f.walk, wr, miss);
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

    /**
     * Delta tracking along `ray` through tracked medium k up to tmax (the
     * nearest surface): tentative collisions from next_collision(), each
     * real with probability mean(mu_t) / mu. Returns the first real
     * collision with the weight prod(mu_n / mean(mu_n)) over the null ones
     * x mu_s / mean(mu_t).
     */
    Collision track_collision(const Tracked &k, const Ray3f &ray, const Float &tmax,
                              Sampler *sampler, Mask active) const {
        // (not MI_MASKED_FUNCTION: on scalar variants it would make the call active)
        ScopedPhase scope_phase(ProfilerPhase::MediumSample);
        auto [mint, maxt] = medium_range(k, ray, tmax, active);
        const ScalarFloat scale = k.scale;
        WalkRay wr = k.volume->walk_ray(ray, Float(scale > 0.f ? m_coarse_depth / scale : 0.f),
                                        active);

        struct TrackState {
            Flight flight;
            UnpolarizedSpectrum weight, sigma_s, sigma_t;
            Float majorant;
            Mask real;
            Sampler *sampler;
            DRJIT_STRUCT(TrackState, flight, weight, sigma_s, sigma_t, majorant, real, sampler)
        } ts = { begin_flight(k, wr, mint, maxt, sampler, active),
                 UnpolarizedSpectrum(1.f),
                 dr::zeros<UnpolarizedSpectrum>(),
                 dr::zeros<UnpolarizedSpectrum>(),
                 Float(0.f),
                 Mask(false),
                 sampler };

        dr::tie(ts) = dr::while_loop(
            dr::make_tuple(ts), [](const TrackState &ts) { return ts.flight.alive; },
            [this, k, ray, wr, mint, scale](TrackState &ts) {
                next_collision(k, wr, ts.flight);
                Mask hit = ts.flight.alive;
                if (dr::none_or<false>(hit))
                    return; // (scalar: the walk ended)
                Float mu = scale * ts.flight.walk.majorant;
                Float xi = ts.sampler->next_1d(hit), u = ts.sampler->next_1d(hit);
                auto [sigma_s, sigma_n, sigma_t] = k.medium->get_scattering_coefficients(
                    interaction_at(k, ray, ts.flight.t, mint), hit);
                DRJIT_MARK_USED(sigma_n);
                Float p_real = dr::mean(sigma_t) / mu;
                Mask real = hit && (xi < p_real), null = hit && !real;
                dr::masked(ts.weight, null) *= (mu - sigma_t) / (mu * (1.f - p_real));
                dr::masked(ts.sigma_s, real) = sigma_s;
                dr::masked(ts.sigma_t, real) = sigma_t;
                dr::masked(ts.majorant, real) = mu;
                dr::masked(ts.flight.tau, null) = -dr::log(1.f - u);
                ts.real |= real;
                ts.flight.alive &= !real;
                count_collision(ts.flight, DeltaLoop, null);
            },
            "volpathlocal: delta tracking");

        Collision c;
        c.real = ts.real;
        c.tripped = ts.flight.tripped;
        const Float &t = ts.flight.t;
        c.mei = interaction_at(k, ray, dr::select(ts.real, t, dr::Infinity<Float>), mint);
        c.mei.p = ray(t);
        c.mei.sigma_s = ts.sigma_s;
        c.mei.sigma_t = ts.sigma_t;
        c.mei.sigma_n = ts.majorant - ts.sigma_t;
        c.mei.combined_extinction = ts.majorant;
        c.weight = ts.weight * ts.sigma_s / dr::mean(ts.sigma_t);
        return c;
    }

    /**
     * Ratio tracking along `ray` through tracked medium k up to tmax: the
     * transmittance estimate prod(mu_n / mu) over the tentative collisions
     * of next_collision().
     */
    std::pair<UnpolarizedSpectrum, UInt32>
    track_transmittance(const Tracked &k, const Ray3f &ray, const Float &tmax,
                        Sampler *sampler, Mask active) const {
        ScopedPhase scope_phase(ProfilerPhase::MediumEvaluate);
        auto [mint, maxt] = medium_range(k, ray, tmax, active);
        const ScalarFloat scale = k.scale;
        WalkRay wr = k.volume->walk_ray(ray, Float(scale > 0.f ? m_coarse_depth / scale : 0.f),
                                        active);

        struct RatioState {
            Flight flight;
            UnpolarizedSpectrum transmittance;
            Sampler *sampler;
            DRJIT_STRUCT(RatioState, flight, transmittance, sampler)
        } rs = { begin_flight(k, wr, mint, maxt, sampler, active), UnpolarizedSpectrum(1.f),
                 sampler };

        dr::tie(rs) = dr::while_loop(
            dr::make_tuple(rs), [](const RatioState &rs) { return rs.flight.alive; },
            [this, k, ray, wr, mint, scale](RatioState &rs) {
                next_collision(k, wr, rs.flight);
                Mask hit = rs.flight.alive;
                if (dr::none_or<false>(hit))
                    return;
                Float mu = scale * rs.flight.walk.majorant;
                Float u = rs.sampler->next_1d(hit);
                auto [sigma_s, sigma_n, sigma_t] = k.medium->get_scattering_coefficients(
                    interaction_at(k, ray, rs.flight.t, mint), hit);
                DRJIT_MARK_USED(sigma_s);
                DRJIT_MARK_USED(sigma_n);
                dr::masked(rs.transmittance, hit) *= (mu - sigma_t) / mu;
                dr::masked(rs.flight.tau, hit) = -dr::log(1.f - u);
                rs.flight.alive &= !(hit && dr::all(rs.transmittance == 0.f));
                count_collision(rs.flight, RatioLoop, hit);
            },
            "volpathlocal: ratio tracking");
        return { rs.transmittance, rs.flight.tripped };
    }

    /// A tentative collision of a flight: counted; past its bound the flight
    /// ends there (as if the walk had ended)
    void count_collision(Flight &f, LoopBound loop, const Mask &hit) const {
        dr::masked(f.collisions, hit) += 1;
        Mask trip = hit && f.alive && f.collisions > f.max_collisions;
        dr::masked(f.tripped, trip) |= (1u << loop);
        f.alive &= !trip;
    }

    // =====================================================================
    //  Loop bounds: every loop ends, whatever the input
    // =====================================================================


    /// One iteration of the path or shadow loop done: `progress` where it
    /// scattered or moved
    void bound_loop(LoopBound loop, const Mask &progress, Mask &active, UInt32 &stalls,
                    UInt32 &steps, UInt32 &tripped) const {
        stalls = dr::select(progress, 0u, stalls + 1u);
        steps += 1u;
        Mask trip = active && (stalls >= kMaxStalls || steps >= kMaxLoopSteps);
        dr::masked(tripped, trip) |= (1u << loop);
        active &= !trip;
    }

    /// Adds a sample's trips (bits of `tripped`) to the counters
    void record_trips(const UInt32 &tripped, const Mask &active) const {
        if constexpr (dr::is_jit_v<Float>) {
            for (uint32_t i = 0; i < LoopCount; ++i)
                dr::scatter_reduce(ReduceOp::Add, m_trips, UInt32(1), UInt32(i),
                                   active && (tripped & (1u << i)) != 0u);
        } else {
            for (uint32_t i = 0; i < LoopCount; ++i)
                if (active && (tripped & (1u << i)))
                    m_scalar_trips[i].fetch_add(1, std::memory_order_relaxed);
        }
    }

    /// Inside the recording of a frozen function (dr.freeze): no reads
    static bool recording() {
        if constexpr (dr::is_jit_v<Float>)
            return jit_flag(JitFlag::FreezingScope);
        else
            return false;
    }

    /// Whether reading the counters evaluates nothing (no pending render,
    /// and not inside a frozen function's recording)
    bool trip_counts_ready() const {
        if constexpr (dr::is_jit_v<Float>) {
            if (recording())
                return false;
            VarState state = jit_var_state(m_trips.index());
            return state == VarState::Evaluated || state == VarState::Literal;
        } else {
            return true;
        }
    }

    std::vector<uint32_t> trip_counts() const {
        std::vector<uint32_t> out(LoopCount);
        if constexpr (dr::is_jit_v<Float>) {
            UInt32 trips = m_trips;
            dr::eval(trips);
            dr::store(out.data(), trips);
        } else {
            for (uint32_t i = 0; i < LoopCount; ++i)
                out[i] = m_scalar_trips[i].load();
        }
        return out;
    }

    /// After a render: warns about the trips since the last report
    void report_trips() const {
        std::vector<uint32_t> trips = trip_counts();
        std::lock_guard<std::mutex> guard(m_prepare_mutex);
        for (uint32_t i = 0; i < LoopCount; ++i) {
            uint32_t fresh = trips[i] - m_trips_reported[i];
            if (fresh)
                Log(Warn, "volpathlocal: the %s loop's bound stopped %u lanes in this render "
                          "(%u in all): a bug or an unsupported input; please report it with "
                          "the scene", kLoopNames[i], fresh, trips[i]);
            m_trips_reported[i] = trips[i];
        }
    }

    // =====================================================================
    //  Helpers
    // =====================================================================

    MI_INLINE Float index_spectrum(const UnpolarizedSpectrum &spec, const UInt32 &idx) const {
        Float m = spec[0];
        if constexpr (is_rgb_v<Spectrum>) {
            dr::masked(m, idx == 1u) = spec[1];
            dr::masked(m, idx == 2u) = spec[2];
        } else {
            DRJIT_MARK_USED(idx);
        }
        return m;
    }

    Float mis_weight(Float pdf_a, Float pdf_b) const {
        pdf_a *= pdf_a;
        pdf_b *= pdf_b;
        Float w = pdf_a / (pdf_a + pdf_b);
        return dr::select(dr::isfinite(w), w, 0.f);
    }

    ScalarFloat m_coarse_depth;
    ScalarFloat m_max_ratio;
    mutable UInt32 m_trips;                             ///< per LoopBound (JIT)
    mutable std::atomic<uint32_t> m_scalar_trips[LoopCount] = {}; ///< (scalar)
    mutable uint32_t m_trips_reported[LoopCount] = {};
    uint32_t m_trip_total_host = 0;                     ///< traverse()'s copy

    MI_TRAVERSE_CB(Base, m_trips)
    mutable std::vector<Tracked> m_tracked;
    mutable std::atomic<const Scene *> m_prepared_for{ nullptr };
    mutable std::mutex m_prepare_mutex;
};

MI_EXPORT_PLUGIN(VolumetricPathLocalMajorants)
NAMESPACE_END(mitsuba)
