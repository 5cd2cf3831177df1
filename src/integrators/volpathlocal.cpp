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
#include <mitsuba/render/volume.h>

#include <nanovdb_mitsuba/emissive_medium.h>
#include <nanovdb_mitsuba/local_majorants.h>
#include <nanovdb_mitsuba/plugin_variants.h>

#include "loop_bounds.h"
#include "tracked_media.h"
#include "tracking.h"

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
     volume (``mi.traverse(volume)["local_majorant_ratio"]``, or
     ``nanovdb_mitsuba.volume_facts``: 0.05 for a real smoke, 1 for a cube of one
     density). Above it the walk would cost its steps and save too few
     null collisions, and the medium is tracked as ``volpath`` does.
     The measurements behind the default: bench/PERF_LOG.md §18-19.
     (Default: 0.5)

 * - coarse_optical_depth
   - |float|
   - Nodes of a NanoVDB tree (lower and upper internal nodes) whose majorant
     gives at most this optical depth along any chord through them are
     crossed as one segment with that majorant instead of node by node: a
     few null collisions there cost less than the steps of the walk.
     ``0`` walks every leaf. (Default: 2)

 * - transmittance
   - |string|
   - How shadow rays estimate a tracked medium's transmittance:
     ``residual`` (residual ratio tracking: the mean of each node of the
     walk, stored beside its majorant, is integrated exactly and only the
     difference is sampled, at the rate of its bound; unbiased, lower
     variance and fewer lookups) or ``ratio`` (ratio tracking against the
     majorants, as before). The measurement behind the default:
     docs/integrator.md. (Default: ``residual``)

 * - emission_sampling
   - |string|
   - How the light of emissive media (``emissiveheterogeneous``) reaches
     the vertices of a path: ``mis`` (next-event estimation toward the
     emission, a point sampled in proportion to what it emits and a shadow
     ray to it, combined by multiple importance sampling with the emission
     that the path's flights collect; unbiased), ``collisions`` (only the
     emission the flights collect, as before) or ``nee`` (next-event
     estimation alone where it applies: for tests; it misses emission that
     its table does not hold, and its variance is unbounded at vertices
     inside the emission). See docs/research/issue35_nee.md.
     (Default: ``mis``)

 * - emission_rate
   - |float|
   - With ``emission_sampling`` ``mis`` or ``nee``: the emission seen from
     the camera is estimated by ratio tracking along the camera's segment,
     at the majorant's rate of tentative collisions plus this many per
     voxel the ray crosses (where the majorant is above 0). More samples of
     the emission along the ray, each weighted by the running transmittance
     estimate: unbiased at any rate. Measured on a fireball (the fire seen
     directly, emission only): 0, 0.25 and 1 give 0.74, 0.15 and 0.07 of
     the collision estimator's variance at 2.1x, 2.2x and 2.7x its time.
     (Default: 1)

 * - shadow_estimates
   - |int|
   - How many independent estimates of a tracked medium's
     transmittance each shadow ray averages. Above 1 it costs that many
     walks and leaves the rest of the path as it is: a measurement of how
     much of an image's variance the shadow rays carry
     (``bench/variance_split.py``), not a setting for renders. (Default: 1)

 * - emission_samples
   - |int|
   - How many points of the emissive media next-event estimation samples
     (each with its own shadow ray) at every vertex, averaged. Above 1 it
     costs that many shadow rays and leaves the rest of the path as it is:
     a measurement of how much of an image's variance next-event
     estimation leaves (``bench/nee_bound.py``), not a setting for renders.
     (Default: 1)

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
- shadow rays estimate transmittance by residual ratio tracking against it:
  each node's mean is integrated exactly, and only what the density
  differs from it is sampled (``transmittance``).

Empty space costs one step per node and no lookup. Every other medium
(homogeneous, ``gridvolume``-based, ...) takes the same code path as in
``volpath``, through the medium's own ``sample_interaction``, so every scene
that ``volpath`` renders renders here, with the same expected value: surfaces
inside media, media inside dielectrics, nested media, emitter sampling with
multiple importance sampling, RGB, spectral, monochrome and polarized
variants.

The code is Mitsuba 3.9.1's ``volpath`` (``src/integrators/volpath.cpp``,
BSD-3-Clause), its structure, names and comments, with each difference
marked ``// volpathlocal:``; the tracking itself is in
``src/integrators/tracking.h``. One difference is one of order: as in
Mitsuba's ``prbvolpath``, a medium vertex and a surface vertex sample their
emitter in one call, after the surface interactions, so that a compiled
kernel holds one shadow ray and not two. Each lane draws the same samples
in the same order as before, so the images are the same: bit for bit in
``scalar_rgb`` on Mitsuba's medium test scenes, within float rounding in
LLVM variants (bench/PERF_LOG.md §33). A medium is tracked when its ``sigma_t``
offers local majorants (``nanovdb_mitsuba/local_majorants.h``), it exposes
a ``scale``, and its own global majorant is ``scale * max()`` (what
``heterogeneous`` does).

Every loop ends: each has a bound on its iterations that a valid ray cannot
reach, and a lane it stops is counted (a warning after the render;
``to_string()``; ``mi.traverse(integrator)["loop_bound_trips"]``).

The estimators (for a tracked medium, with majorant :math:`\bar\mu(t)` =
``scale`` times the node's bound, extinction :math:`\mu_t`, scattering
:math:`\mu_s`, null :math:`\mu_n = \bar\mu - \mu_t`, per channel):

- delta tracking: tentative collisions are sampled with density
  :math:`\bar\mu(t) \exp(-\int \bar\mu)`; each is real with probability
  :math:`P_r = \mathrm{mean}(\mu_t) / \bar\mu`, weight
  :math:`\mu_s / \mathrm{mean}(\mu_t)`, and null otherwise, weight
  :math:`\mu_n / \mathrm{mean}(\mu_n)` (1 for a grey extinction);
- ratio tracking: the transmittance estimate is
  :math:`\prod \mu_n / \bar\mu` over the tentative collisions;
- emission (an ``emissiveheterogeneous`` medium, which Mitsuba's own
  integrators render without it): at every tentative collision of delta
  tracking, real or null, the path adds its throughput times the null
  weights so far times :math:`\sigma_a L_e / \bar\mu`, whose mean is the
  emission the ray collects (pbrt-v4's estimator; tracking.h). An emissive
  medium is always tracked through the walk, whatever
  ``max_majorant_ratio``;
- next-event estimation toward emissive media (``emission_sampling``):
  from each vertex that samples emitters, a medium chosen by its emitted
  power, a point :math:`x` of it with density :math:`p(x)` per unit
  volume (its emission table: the emission grid's leaves cut into blocks
  of 2³ voxels, weighted by :math:`\sigma_a L_e`), and
  :math:`f\,\hat T\,\sigma_a L_e\,w / (p\,r^2)`; the emission that the
  next flight collects at :math:`x` is weighted by :math:`1 - w`, with
  :math:`w = (p r^2)^2 / ((p r^2)^2 + p_\text{dir}^2)` (the power
  heuristic, with 1 in place of the flight's probability of reaching
  :math:`x`, so that both sides compute the same weight).

.. tabs::
    .. code-tab:: xml

        <integrator type="volpathlocal">
            <integer name="max_depth" value="64"/>
        </integrator>

    .. code-tab:: python

        'type': 'volpathlocal',
        'max_depth': 64

*/

// volpathlocal: a class of its own name, final
template <typename Float, typename Spectrum>
class VolumetricPathLocalMajorants final : public MonteCarloIntegrator<Float, Spectrum> {
public:
    MI_IMPORT_BASE(MonteCarloIntegrator, m_max_depth, m_rr_depth, m_hide_emitters)
    // volpathlocal: Sensor and Volume, the tracker's types, the two properties
    MI_IMPORT_TYPES(Scene, Sampler, Sensor, Emitter, EmitterPtr, BSDF, BSDFPtr,
                    Medium, MediumPtr, PhaseFunction, PhaseFunctionPtr,
                    PhaseFunctionContext, Volume)
    using Tracker = Tracking<Float, Spectrum>;
    using TrackedMedium = typename Tracker::TrackedMedium;
    using Trips = LoopTrips<Float>;

    VolumetricPathLocalMajorants(const Properties &props) : Base(props) {
        m_coarse_depth = props.get<ScalarFloat>("coarse_optical_depth", 2.f);
        if (!(m_coarse_depth >= 0.f) || !std::isfinite(m_coarse_depth))
            Throw("volpathlocal: coarse_optical_depth must be a finite value >= 0, got %f",
                  m_coarse_depth);
        // (an opaque variable: integrators of other depths share kernels)
        m_coarse_depth_var = dr::opaque<Float>(m_coarse_depth);
        // The same for the depths (kernel parameters, where volpath's are
        // literals): renders of other max_depth and rr_depth share kernels
        m_max_depth_var = dr::opaque<UInt32>((uint32_t) m_max_depth);
        m_rr_depth_var = dr::opaque<UInt32>((uint32_t) m_rr_depth);
        int shadow = props.get<int>("shadow_estimates", 1);
        if (shadow < 1)
            Throw("volpathlocal: shadow_estimates must be >= 1, got %d", shadow);
        m_shadow_estimates = (uint32_t) shadow;
        int emission_samples = props.get<int>("emission_samples", 1);
        if (emission_samples < 1)
            Throw("volpathlocal: emission_samples must be >= 1, got %d", emission_samples);
        m_emission_samples = (uint32_t) emission_samples;
        std::string estimator = props.get<std::string>("transmittance", "residual");
        if (estimator != "residual" && estimator != "ratio")
            Throw("volpathlocal: transmittance must be \"residual\" or \"ratio\", got \"%s\"",
                  estimator);
        m_residual = estimator == "residual";
        std::string emission = props.get<std::string>("emission_sampling", "mis");
        if (emission == "mis")
            m_emission_sampling = EmissionSampling::Mis;
        else if (emission == "collisions")
            m_emission_sampling = EmissionSampling::Collisions;
        else if (emission == "nee")
            m_emission_sampling = EmissionSampling::Nee;
        else
            Throw("volpathlocal: emission_sampling must be \"mis\", \"collisions\" or \"nee\", "
                  "got \"%s\"", emission);
        m_emission_rate = props.get<ScalarFloat>("emission_rate", 1.f);
        if (!(m_emission_rate >= 0.f && std::isfinite(m_emission_rate)))
            Throw("volpathlocal: emission_rate must be a finite value >= 0, got %f",
                  m_emission_rate);
        m_max_ratio = props.get<ScalarFloat>("max_majorant_ratio", 0.5f);
        if (!(m_max_ratio >= 0.f && m_max_ratio <= 1.f))
            Throw("volpathlocal: max_majorant_ratio must be in [0, 1], got %f", m_max_ratio);
    }

    // volpathlocal: which media to track, found anew for every render; the
    // loop bounds' trips reported after it
    TensorXf render(Scene *scene, Sensor *sensor, UInt32 seed = 0, uint32_t spp = 0,
                    bool develop = true, bool evaluate = true) override {
        if (m_trips.ready()) // trips of earlier renders not reported yet
            m_trips.report();
        prepare(scene, true);
        TensorXf image = Base::render(scene, sensor, seed, spp, develop, evaluate);
        // (a JIT image not evaluated yet: its trips are reported by the next
        // render(), to_string() or traverse(), so as not to evaluate it here)
        if ((evaluate && !recording_frozen_function<Float>()) || m_trips.ready())
            m_trips.report();
        return image;
    }

    void traverse(TraversalCallback *cb) override {
        Base::traverse(cb);
        // How many lanes the loop bounds stopped so far (per loop in
        // to_string()): 0 unless something is wrong
        m_trip_total_host = 0;
        for (uint32_t n : m_trips.counts())
            m_trip_total_host += n;
        cb->put("loop_bound_trips", m_trip_total_host, ParamFlags::NonDifferentiable);
        // How many media the last render tracked through the walk
        m_tracked_host = (uint32_t) m_tracked.size();
        cb->put("tracked_media", m_tracked_host, ParamFlags::NonDifferentiable);
    }

    //! @{ \name Sampling the RTE: volpath's path, tracked media by delta tracking

    MI_INLINE
    Float index_spectrum(const UnpolarizedSpectrum &spec, const UInt32 &idx) const {
        Float m = spec[0];
        if constexpr (is_rgb_v<Spectrum>) { // Handle RGB rendering
            dr::masked(m, idx == 1u) = spec[1];
            dr::masked(m, idx == 2u) = spec[2];
        } else {
            DRJIT_MARK_USED(idx);
        }
        return m;
    }

    std::pair<Spectrum, Mask> sample(const Scene *scene,
                                     Sampler *sampler,
                                     const RayDifferential3f &ray_,
                                     const Medium *initial_medium,
                                     Float * /* aovs */,
                                     Mask active) const override {
        MI_MASKED_FUNCTION(ProfilerPhase::SamplingIntegratorSample, active);
        prepare(scene, false); // volpathlocal: a scene that render() did not see

        // If there is an environment emitter and emitters are visible: all rays will be valid
        // Otherwise, it will depend on whether a valid interaction is sampled
        Mask valid_ray = !m_hide_emitters && (scene->environment() != nullptr);

        // For now, don't use ray differentials
        Ray3f ray = ray_;

        // Tracks radiance scaling due to index of refraction changes
        Float eta(1.f);

        Spectrum throughput(1.f), result(0.f);
        MediumPtr medium = initial_medium;
        MediumInteraction3f mei = dr::zeros<MediumInteraction3f>();
        Mask specular_chain = active && !m_hide_emitters;
        UInt32 depth = 0;

        UInt32 channel = 0;
        if (is_rgb_v<Spectrum>) {
            uint32_t n_channels = (uint32_t) dr::size_v<Spectrum>;
            channel = (UInt32) dr::minimum(sampler->next_1d(active) * n_channels, n_channels - 1);
        }

        SurfaceInteraction3f si = dr::zeros<SurfaceInteraction3f>();
        Mask needs_intersection = true;
        Interaction3f last_scatter_event = dr::zeros<Interaction3f>();
        Float last_scatter_direction_pdf = 1.f;

        /* Set up a Dr.Jit loop (optimizes away to a normal loop in scalar mode,
           generates wavefront or megakernel renderer based on configuration).
           Register everything that changes as part of the loop here */
        struct LoopState {
            Mask active;
            UInt32 depth;
            Ray3f ray;
            Spectrum throughput;
            Spectrum result;
            SurfaceInteraction3f si;
            MediumInteraction3f mei;
            MediumPtr medium;
            Float eta;
            Interaction3f last_scatter_event;
            Float last_scatter_direction_pdf;
            Mask needs_intersection;
            Mask specular_chain;
            Mask valid_ray;
            UInt32 stalls, steps, tripped; // volpathlocal: the loop bounds
            Sampler* sampler;

            DRJIT_STRUCT(LoopState, active, depth, ray, throughput, result, \
                si, mei, medium, eta, last_scatter_event, \
                last_scatter_direction_pdf, needs_intersection, \
                specular_chain, valid_ray, stalls, steps, tripped, sampler) // volpathlocal: the loop bounds
        } ls = {
            active,
            depth,
            ray,
            throughput,
            result,
            si,
            mei,
            medium,
            eta,
            last_scatter_event,
            last_scatter_direction_pdf,
            needs_intersection,
            specular_chain,
            valid_ray,
            UInt32(0), UInt32(0), UInt32(0), // volpathlocal: stalls, steps, tripped
            sampler
        };

        dr::tie(ls) = dr::while_loop(dr::make_tuple(ls),
            [](const LoopState& ls) { return ls.active; },
            [this, scene, channel](LoopState& ls) {

            Mask& active = ls.active;
            UInt32& depth = ls.depth;
            Ray3f& ray = ls.ray;
            Spectrum& throughput = ls.throughput;
            Spectrum& result = ls.result;
            SurfaceInteraction3f& si = ls.si;
            MediumInteraction3f& mei = ls.mei;
            MediumPtr& medium = ls.medium;
            Float& eta = ls.eta;
            Interaction3f& last_scatter_event = ls.last_scatter_event;
            Float& last_scatter_direction_pdf = ls.last_scatter_direction_pdf;
            Mask& needs_intersection = ls.needs_intersection;
            Mask& specular_chain = ls.specular_chain;
            Mask& valid_ray = ls.valid_ray;
            Sampler* sampler = ls.sampler;
            // volpathlocal: what the loop bound compares (see bound_loop)
            const Ray3f ray_before = ray;
            const UInt32 depth_before = depth;

            // ----------------- Handle termination of paths ------------------
            // Russian roulette: try to keep path weights equal to one, while accounting for the
            // solid angle compression at refractive index boundaries. Stop with at least some
            // probability to avoid getting stuck (e.g. due to total internal reflection)
            active &= dr::any(unpolarized_spectrum(throughput) != 0.f);
            Float q = dr::minimum(dr::max(unpolarized_spectrum(throughput)) * dr::square(eta), .95f);
            Mask perform_rr = (depth > m_rr_depth_var); // volpathlocal: opaque depths
            active &= sampler->next_1d(active) < q || !perform_rr;
            dr::masked(throughput, perform_rr) *= dr::rcp(dr::detach(q));

            active &= depth < m_max_depth_var; // volpathlocal: opaque depths
            if (dr::none_or<false>(active))
                return;

            // ----------------------- Sampling the RTE -----------------------
            Mask active_medium  = active && (medium != nullptr);
            Mask active_surface = active && !active_medium;
            Mask act_null_scatter = false, act_medium_scatter = false,
                 escaped_medium = false;

            // volpathlocal: lanes in a tracked medium find their collision by
            // delta tracking through its walk (below); the others sample theirs
            // as volpath does
            Mask tracked = tracked_lanes(medium, active_medium);
            Mask sampled = active_medium && !tracked;

            // If the medium does not have a spectrally varying extinction,
            // we can perform a few optimizations to speed up rendering
            Mask is_spectral = sampled; // volpathlocal: not tracked lanes (their weights: tracking)
            Mask not_spectral = false;
            if (dr::any_or<true>(sampled)) {
                is_spectral &= medium->has_spectral_extinction();
                not_spectral = !is_spectral && sampled; // volpathlocal: sampled lanes
            }

            if (dr::any_or<true>(active_medium)) {
                // volpathlocal: tracked lanes get theirs from tracking (below):
                // not sampled here (a scalar call would run whatever its mask,
                // and a masked JIT call returns zeros: t = 0, "valid")
                Float u = sampler->next_1d(active_medium);
                if (dr::any_or<true>(sampled))
                    mei = medium->sample_interaction(ray, u, channel, sampled);
                dr::masked(mei.t, tracked) = dr::Infinity<Float>;
                dr::masked(ray.maxt, sampled && medium->is_homogeneous() && mei.is_valid()) = mei.t;
                Mask intersect = needs_intersection && active_medium;
                if (dr::any_or<true>(intersect))
                    dr::masked(si, intersect) = scene->ray_intersect(ray, intersect);
                needs_intersection &= !active_medium;

                // volpathlocal: delta tracking up to the nearest surface; the
                // emission it collects weighed against next-event
                // estimation from the last scattering vertex (where that
                // vertex sampled the emissive media: not the camera's, not
                // after a specular one)
                typename Tracker::EmissionMis emission_mis{
                    depth > 0u && !specular_chain, last_scatter_event.p,
                    last_scatter_direction_pdf, m_emission_sampling == EmissionSampling::Nee };
                const bool camera_emission = m_emission_sampling != EmissionSampling::Collisions;
                for (const TrackedMedium &k : m_tracked) {
                    Mask in_k = tracked && (medium == MediumPtr(k.medium));
                    if (dr::none_or<false>(in_k))
                        continue; // (scalar variants: not this medium)
                    // volpathlocal: the camera's segment through an emissive
                    // medium: its collision and the emission along all of it
                    // in one walk (tracking.h camera_tracking)
                    Mask camera = in_k && depth == 0u;
                    if (k.emissive && camera_emission && dr::any_or<true>(camera)) {
                        typename Tracker::Collision c = Tracker::camera_tracking(
                            k, ray, si.t, m_coarse_depth_var, sampler, camera, m_emission_rate);
                        dr::masked(mei, camera) = c.mei;
                        dr::masked(result, camera) += throughput * depolarizer<Spectrum>(c.emitted);
                        dr::masked(throughput, camera) *= c.weight;
                        dr::masked(ls.tripped, camera) |= c.tripped;
                        in_k &= !camera;
                        if (dr::none_or<false>(in_k))
                            continue;
                    }
                    typename Tracker::Collision c = Tracker::delta_tracking(
                        k, ray, si.t, m_coarse_depth_var, sampler, in_k, emission_mis);
                    dr::masked(mei, in_k) = c.mei;
                    // volpathlocal: an emissive medium's emission along the flight
                    if (k.emissive)
                        dr::masked(result, in_k) +=
                            throughput * depolarizer<Spectrum>(c.emitted);
                    dr::masked(throughput, in_k) *= c.weight;
                    dr::masked(ls.tripped, in_k) |= c.tripped;
                }

                dr::masked(mei.t, active_medium && (si.t < mei.t)) = dr::Infinity<Float>;
                // volpathlocal: a flight that leaves the medium without a
                // collision and meets no surface (an unenclosed medium) keeps
                // its throughput, its weight tr / pdf being 1 in the limit;
                // volpath computes 0 / 0 there and loses the path
                Mask weighted = is_spectral && (mei.is_valid() || si.is_valid());
                if (dr::any_or<true>(weighted)) {
                    auto [tr, free_flight_pdf] = medium->transmittance_eval_pdf(mei, si, weighted);
                    Float tr_pdf = index_spectrum(free_flight_pdf, channel);
                    // volpathlocal: weighted lanes (above)
                    dr::masked(throughput, weighted) *= dr::select(tr_pdf > 0.f, tr / tr_pdf, 0.f);
                }

                escaped_medium = active_medium && !mei.is_valid();
                active_medium &= mei.is_valid();

                // Handle null and real scatter events
                Float null_scatter_prob = dr::mean(mei.sigma_n / mei.combined_extinction);
                Mask null_scatter = sampler->next_1d(active_medium) < null_scatter_prob;
                null_scatter &= !tracked; // volpathlocal: tracking resolved its null collisions

                act_null_scatter |= null_scatter && active_medium;
                act_medium_scatter |= !act_null_scatter && active_medium;

                if (dr::any_or<true>(is_spectral && act_null_scatter))
                    dr::masked(throughput, is_spectral && act_null_scatter) *=
                        mei.sigma_n / null_scatter_prob;

                dr::masked(depth, act_medium_scatter) += 1;
                dr::masked(last_scatter_event, act_medium_scatter) = mei;
            }

            // Dont estimate lighting if we exceeded number of bounces
            active &= depth < m_max_depth_var; // volpathlocal: opaque depths
            act_medium_scatter &= active;

            if (dr::any_or<true>(act_null_scatter)) {
                dr::masked(ray.o, act_null_scatter) = mei.p;
                dr::masked(si.t, act_null_scatter) = si.t - mei.t;
            }

            // volpathlocal: the phase function and the lanes that sample an
            // emitter from their medium vertex, kept for the emitter sampling
            // and phase sampling below the surface interactions: one
            // sample_emitter call serves medium and surface vertices alike
            // (the order of Mitsuba's prbvolpath), so that a kernel traces
            // one shadow ray, and one walk of each tracked medium for it
            PhaseFunctionContext phase_ctx(sampler);
            PhaseFunctionPtr phase = nullptr;
            Mask active_e_medium = false;
            if (dr::any_or<true>(act_medium_scatter)) {
                if (dr::any_or<true>(is_spectral))
                    dr::masked(throughput, is_spectral && act_medium_scatter) *=
                        mei.sigma_s / dr::mean(mei.sigma_t / mei.combined_extinction);
                if (dr::any_or<true>(not_spectral))
                    dr::masked(throughput, not_spectral && act_medium_scatter) *= mei.sigma_s / mei.sigma_t;

                phase = mei.medium->phase_function(); // volpathlocal: (declared above)

                // --------------------- Emitter sampling ---------------------
                Mask sample_emitters = mei.medium->use_emitter_sampling();
                valid_ray |= act_medium_scatter;
                specular_chain &= !act_medium_scatter;
                specular_chain |= act_medium_scatter && !sample_emitters;

                // volpathlocal: sampled below, with the surface vertices'
                active_e_medium = act_medium_scatter && sample_emitters;
                dr::masked(phase, !act_medium_scatter) = nullptr;
            }

            // --------------------- Surface Interactions ---------------------
            active_surface |= escaped_medium;
            Mask intersect = active_surface && needs_intersection;
            if (dr::any_or<true>(intersect))
                dr::masked(si, intersect) = scene->ray_intersect(ray, intersect);

            if (dr::any_or<true>(active_surface)) {
                // ---------------------- Hide area emitters ----------------------
                if (m_hide_emitters && dr::any_or<true>(ls.depth == 0u)) {
                    // Are we on the first segment and did we hit an area emitter?
                    // If so, skip all area emitters along this ray
                    Mask skip_emitters = si.is_valid() &&
                                         (si.shape->emitter() != nullptr) &&
                                         (ls.depth == 0) &&
                                         intersect;

                    if (dr::any_or<true>(skip_emitters)) {
                        Ray3f ray = si.spawn_ray(ls.ray.d);
                        PreliminaryIntersection3f pi =
                            Base::skip_area_emitters(scene, ray, true, skip_emitters);
                        SurfaceInteraction3f si_after_skip =
                            pi.compute_surface_interaction(ray, +RayFlags::All, skip_emitters);
                        dr::masked(si, skip_emitters) = si_after_skip;
                    }
                }

                // ---------------- Intersection with emitters ----------------
                Mask ray_from_camera = active_surface && (depth == 0u);
                Mask count_direct = ray_from_camera || specular_chain;
                EmitterPtr emitter = si.emitter(scene);
                Mask active_e = active_surface && (emitter != nullptr) &&
                                !((depth == 0u) && m_hide_emitters);
                if (dr::any_or<true>(active_e)) {
                    Float emitter_pdf = 1.0f;
                    if (dr::any_or<true>(active_e && !count_direct)) {
                        // Get the PDF of sampling this emitter using next event estimation
                        DirectionSample3f ds(scene, si, last_scatter_event);
                        emitter_pdf = scene->pdf_emitter_direction(last_scatter_event, ds, active_e);
                    }
                    Spectrum emitted = emitter->eval(si, active_e);
                    Spectrum contrib = dr::select(count_direct, throughput * emitted,
                                                  throughput * mis_weight(last_scatter_direction_pdf, emitter_pdf) * emitted);
                    dr::masked(result, active_e) += contrib;
                }
            }
            active_surface &= si.is_valid();
            // volpathlocal: the surface vertices' BSDF, then emitter sampling
            // for both kinds of vertex (one call), then phase sampling (from
            // the medium block above), then BSDF sampling
            BSDFContext ctx;
            BSDFPtr bsdf = nullptr;
            Mask active_e_surface = false;
            if (dr::any_or<true>(active_surface)) {
                // --------------------- Emitter sampling ---------------------
                bsdf = si.bsdf(ray); // volpathlocal: (declared above)
                active_e_surface = active_surface && has_flag(bsdf->flags(), BSDFFlags::Smooth) && (depth + 1 < m_max_depth_var); // volpathlocal: opaque depths, declared above
            }
            // volpathlocal: medium and surface vertices in one call
            Mask active_e = active_e_medium || active_e_surface;
            if (likely(dr::any_or<true>(active_e))) {
                // volpathlocal: the shadow ray's loop-bound trips kept
                auto [emitted, ds] = sample_emitter(mei, si, active_e_medium,
                                                    active_e_surface, scene, sampler,
                                                    medium, channel, ls.tripped, active_e);
                if (dr::any_or<true>(active_e_medium)) { // volpathlocal: (from the medium block)
                    auto [phase_val, phase_pdf] = phase->eval_pdf(phase_ctx, mei, ds.d, active_e_medium);
                    dr::masked(result, active_e_medium) += throughput * phase_val * emitted *
                                                           mis_weight(ds.pdf, dr::select(ds.delta, 0.f, phase_pdf));
                }

                if (dr::any_or<true>(active_e_surface)) { // volpathlocal: surface vertices
                    // Query the BSDF for that emitter-sampled direction
                    Vector3f wo       = si.to_local(ds.d);
                    Spectrum bsdf_val = bsdf->eval(ctx, si, wo, active_e_surface);
                    bsdf_val = si.to_world_mueller(bsdf_val, -wo, si.wi);

                    // Determine probability of having sampled that same
                    // direction using BSDF sampling.
                    // volpathlocal: (active_e_surface: the surface lanes of active_e)
                    Float bsdf_pdf = bsdf->pdf(ctx, si, wo, active_e_surface);
                    result[active_e_surface] += throughput * bsdf_val * mis_weight(ds.pdf, dr::select(ds.delta, 0.f, bsdf_pdf)) * emitted;
                }
            }

            // volpathlocal: next-event estimation toward the emissive media
            // (issue 35), from the same vertices, with MIS against the
            // emission their flights collect (tracking.h's EmissionMis)
            if (m_nee_media && dr::any_or<true>(active_e)) {
                // The phase function's or BSDF's value and pdf toward the
                // sampled point (its MIS weight is known before the shadow
                // ray: sample_emissive_media's Russian roulette)
                auto toward = [&](const Vector3f &d) {
                    Spectrum f(0.f);
                    Float p_dir = 0.f;
                    if (dr::any_or<true>(active_e_medium)) {
                        auto [phase_val, phase_pdf] = phase->eval_pdf(phase_ctx, mei, d, active_e_medium);
                        dr::masked(f, active_e_medium) = phase_val;
                        dr::masked(p_dir, active_e_medium) = phase_pdf;
                    }
                    if (dr::any_or<true>(active_e_surface)) {
                        Vector3f wo = si.to_local(d);
                        Spectrum bsdf_val = bsdf->eval(ctx, si, wo, active_e_surface);
                        dr::masked(f, active_e_surface) = si.to_world_mueller(bsdf_val, -wo, si.wi);
                        dr::masked(p_dir, active_e_surface) = bsdf->pdf(ctx, si, wo, active_e_surface);
                    }
                    return std::make_pair(f, p_dir);
                };
                // (emission_samples: that many, averaged; a measurement)
                for (uint32_t i = 0; i < m_emission_samples; ++i) {
                    Spectrum contribution = sample_emissive_media(
                        mei, si, active_e_medium, active_e_surface, scene, sampler, medium,
                        channel, ls.tripped, active_e, toward);
                    dr::masked(result, active_e) +=
                        throughput * contribution * (1.f / (float) m_emission_samples);
                }
            }

            // volpathlocal: phase sampling, from the medium block above
            if (dr::any_or<true>(act_medium_scatter)) {
                // ------------------ Phase function sampling -----------------
                auto [wo, phase_weight, phase_pdf] = phase->sample(phase_ctx, mei,
                    sampler->next_1d(act_medium_scatter),
                    sampler->next_2d(act_medium_scatter),
                    act_medium_scatter);
                act_medium_scatter &= phase_pdf > 0.f;
                Ray3f new_ray  = mei.spawn_ray(wo);
                dr::masked(ray, act_medium_scatter) = new_ray;
                needs_intersection |= act_medium_scatter;
                dr::masked(last_scatter_direction_pdf, act_medium_scatter) = phase_pdf;
                dr::masked(throughput, act_medium_scatter) *= phase_weight;
            }

            if (dr::any_or<true>(active_surface)) {
                // ----------------------- BSDF sampling ----------------------
                auto [bs, bsdf_val] = bsdf->sample(ctx, si, sampler->next_1d(active_surface),
                                                   sampler->next_2d(active_surface), active_surface);
                bsdf_val = si.to_world_mueller(bsdf_val, -bs.wo, si.wi);

                dr::masked(throughput, active_surface) *= bsdf_val;
                dr::masked(eta, active_surface) *= bs.eta;

                Ray3f bsdf_ray                  = si.spawn_ray(si.to_world(bs.wo));
                dr::masked(ray, active_surface) = bsdf_ray;
                needs_intersection |= active_surface;

                Mask non_null_bsdf = active_surface && !has_flag(bs.sampled_type, BSDFFlags::Null);
                dr::masked(depth, non_null_bsdf) += 1;

                // update the last scatter PDF event if we encountered a non-null scatter event
                dr::masked(last_scatter_event, non_null_bsdf) = si;
                dr::masked(last_scatter_direction_pdf, non_null_bsdf) = bs.pdf;

                valid_ray |= non_null_bsdf;
                specular_chain |= non_null_bsdf && has_flag(bs.sampled_type, BSDFFlags::Delta);
                specular_chain &= !(active_surface && has_flag(bs.sampled_type, BSDFFlags::Smooth));
                act_null_scatter |= active_surface && has_flag(bs.sampled_type, BSDFFlags::Null);
                Mask has_medium_trans                = active_surface && si.is_medium_transition();
                dr::masked(medium, has_medium_trans) = si.target_medium(ray.d);
            }
            active &= (active_surface | active_medium);

            // volpathlocal: the loop bound
            Mask moved = depth != depth_before || dr::any(ray.o != ray_before.o) ||
                         dr::any(ray.d != ray_before.d);
            Trips::bound_loop(PathLoop, moved, active, ls.stalls, ls.steps, ls.tripped);
        },
        "volpathlocal: path");

        m_trips.record(ls.tripped, active); // volpathlocal
        return { ls.result, ls.valid_ray };
    }


    /// Samples an emitter in the scene and evaluates its attenuated contribution
    // volpathlocal: from a medium vertex (mei, active_medium) or a surface
    // one (si, active_surface) in one call, as Mitsuba's prbvolpath does; tripped
    std::tuple<Spectrum, DirectionSample3f>
    sample_emitter(const MediumInteraction3f &mei, const SurfaceInteraction3f &si_ref,
                   const Mask &active_medium, const Mask &active_surface,
                   const Scene *scene, Sampler *sampler, MediumPtr medium,
                   UInt32 channel, UInt32 &tripped, Mask active) const {
        Interaction3f ref_interaction = dr::zeros<Interaction3f>();
        dr::masked(ref_interaction, active_medium) = Interaction3f(mei);
        dr::masked(ref_interaction, active_surface) = Interaction3f(si_ref);

        auto [ds, emitter_val] = scene->sample_emitter_direction(ref_interaction, sampler->next_2d(active), false, active);
        dr::masked(emitter_val, ds.pdf == 0.f) = 0.f;
        active &= (ds.pdf != 0.f);

        if (dr::none_or<false>(active)) {
            return { emitter_val, ds };
        }

        Ray3f ray = ref_interaction.spawn_ray_to(ds.p);
        // volpathlocal: the shadow ray's loop in trace_shadow (below), shared
        // with next-event estimation toward emissive media
        auto [transmittance_, end_medium] = trace_shadow(ray, si_ref, active_surface, ds, scene,
                                                         sampler, medium, channel, tripped, active);
        DRJIT_MARK_USED(end_medium);
        return { transmittance_ * emitter_val, ds };
    }

    // volpathlocal: next-event estimation toward the emissive media (issue
    // 35; docs/research/issue35_nee.md): a medium chosen by its emitted
    // power, a point x of it by its emission table, the shadow ray to x;
    // returns f T sigma_a(x) Le(x) w / (p r^2) (0 unless the shadow ray
    // ends in that medium), p the point's density per unit volume, f and
    // the direction's pdf p_dir from toward(d) (the vertex's phase function
    // or BSDF), w the power heuristic's weight of p r^2 against p_dir.
    // Russian roulette before the shadow ray: a point whose MIS weight is
    // below NEE_RR (the collision estimator covers it: close to the vertex,
    // where r^2 is small) is traced with probability w / NEE_RR, divided by
    // it; so is nothing whose emission at x is 0
    static constexpr float NEE_RR = 0.25f;

    template <typename Toward>
    Spectrum sample_emissive_media(const MediumInteraction3f &mei, const SurfaceInteraction3f &si_ref,
                                   const Mask &active_medium, const Mask &active_surface,
                                   const Scene *scene, Sampler *sampler, MediumPtr medium,
                                   UInt32 channel, UInt32 &tripped, Mask active,
                                   Toward &&toward) const {
        Interaction3f ref = dr::zeros<Interaction3f>();
        dr::masked(ref, active_medium) = Interaction3f(mei);
        dr::masked(ref, active_surface) = Interaction3f(si_ref);
        Float u = sampler->next_1d(active);
        Point2f u2 = sampler->next_2d(active);
        Point3f u3(u2.x(), u2.y(), sampler->next_1d(active));
        // The medium (by its power), a point x of it, and what x emits:
        // sigma_a Le of that medium
        MediumInteraction3f mx = dr::zeros<MediumInteraction3f>();
        mx.t = 0.f;
        mx.time = ref.time;
        mx.wavelengths = ref.wavelengths;
        Point3f x = dr::zeros<Point3f>();
        Float pdf = 0.f;
        MediumPtr target = nullptr;
        UnpolarizedSpectrum emitted(0.f);
        Float lo = 0.f;
        for (size_t i = 0; i < m_tracked.size(); ++i) {
            const TrackedMedium &k = m_tracked[i];
            if (!k.nee)
                continue;
            Float hi = lo + k.select;
            Mask pick = active && u >= lo && (u < hi || i + 1 == m_last_nee);
            if (dr::any_or<true>(pick)) {
                Float v = dr::minimum((u - lo) / k.select, dr::OneMinusEpsilon<Float>);
                auto [p, pdf_k] = k.emissive->sample_emission_point(v, u3, pick);
                dr::masked(x, pick) = p;
                dr::masked(pdf, pick) = k.select * pdf_k;
                dr::masked(target, pick) = MediumPtr(k.medium);
                mx.p = p;
                mx.medium = k.medium;
                auto [sigma_s, sigma_n, sigma_t] = k.medium->get_scattering_coefficients(mx, pick);
                DRJIT_MARK_USED(sigma_n);
                dr::masked(emitted, pick) = (sigma_t - sigma_s) * k.emissive->eval_emission(mx, pick);
            }
            lo = hi;
        }
        active &= pdf > 0.f && dr::any(emitted != 0.f);
        Vector3f d = x - ref.p;
        Float r2 = dr::squared_norm(d);
        d *= dr::rsqrt(r2);
        active &= r2 > 0.f;
        Spectrum result(0.f);
        if (dr::none_or<false>(active))
            return result;

        DirectionSample3f ds = dr::zeros<DirectionSample3f>();
        ds.p = x;
        ds.d = d;
        ds.dist = dr::sqrt(r2);
        ds.pdf = pdf * r2;

        // The MIS weight, and the Russian roulette on it
        auto [f, p_dir] = toward(d);
        Float w = m_emission_sampling == EmissionSampling::Nee
                      ? Float(1.f) : mis_weight(ds.pdf, p_dir);
        Float q = dr::minimum(w * (1.f / NEE_RR), 1.f);
        active &= (q >= 1.f) || (sampler->next_1d(active) < q);
        if (dr::none_or<false>(active))
            return result;

        Ray3f ray = ref.spawn_ray_to(x);
        auto [tr, end_medium] = trace_shadow(ray, si_ref, active_surface, ds, scene, sampler,
                                             medium, channel, tripped, active);
        active &= end_medium == target;
        dr::masked(result, active) = f * tr * depolarizer<Spectrum>(emitted) * (w / (q * ds.pdf));
        return result;
    }

    // volpathlocal: sample_emitter's shadow ray, from `ray` (a ray from the
    // vertex to ds.p) through media and null surfaces; returns its
    // transmittance and the medium it ends in
    std::pair<Spectrum, MediumPtr>
    trace_shadow(Ray3f ray, const SurfaceInteraction3f &si_ref, const Mask &active_surface,
                 const DirectionSample3f &ds, const Scene *scene, Sampler *sampler,
                 MediumPtr medium, UInt32 channel, UInt32 &tripped, Mask active) const {
        Spectrum transmittance(1.0f);
        Float max_dist = ray.maxt;

        // Potentially escaping the medium if this is the current medium's boundary
        // volpathlocal: surface vertices only (si_ref: no medium vertex's)
        if (dr::any_or<true>(active_surface)) {
            Mask transition = active_surface && si_ref.is_medium_transition();
            dr::masked(medium, transition) = si_ref.target_medium(ray.d);
        }

        Float total_dist = 0.f;
        SurfaceInteraction3f si = dr::zeros<SurfaceInteraction3f>();
        Mask needs_intersection = true;
        DirectionSample3f dir_sample = ds;

        struct LoopState {
            Mask active;
            Ray3f ray;
            Float total_dist;
            Mask needs_intersection;
            MediumPtr medium;
            SurfaceInteraction3f si;
            Spectrum transmittance;
            DirectionSample3f dir_sample;
            UInt32 stalls, steps, tripped; // volpathlocal: the loop bounds
            Sampler* sampler;

            DRJIT_STRUCT(LoopState, active, ray, total_dist, \
                needs_intersection, medium, si, transmittance, \
                dir_sample, stalls, steps, tripped, sampler) // volpathlocal: the loop bounds
        } ls = {
            active,
            ray,
            total_dist,
            needs_intersection,
            medium,
            si,
            transmittance,
            dir_sample,
            UInt32(0), UInt32(0), UInt32(0), // volpathlocal: stalls, steps, tripped
            sampler
        };

        dr::tie(ls) = dr::while_loop(dr::make_tuple(ls),
            [](const LoopState& ls) { return dr::detach(ls.active); },
            [this, scene, channel, max_dist](LoopState& ls) {

            Mask& active = ls.active;
            Ray3f& ray = ls.ray;
            Float& total_dist = ls.total_dist;
            Mask& needs_intersection = ls.needs_intersection;
            MediumPtr& medium = ls.medium;
            SurfaceInteraction3f& si = ls.si;
            Spectrum& transmittance = ls.transmittance;
            DirectionSample3f& dir_sample = ls.dir_sample;
            Sampler* sampler = ls.sampler;
            const Point3f origin_before = ray.o; // volpathlocal: the loop bound

            Float remaining_dist = max_dist - total_dist;
            ray.maxt = remaining_dist;
            active &= remaining_dist > 0.f;
            if (dr::none_or<false>(active))
                return;

            Mask escaped_medium = false;
            Mask active_medium  = active && (medium != nullptr);
            Mask active_surface = active && !active_medium;

            if (dr::any_or<true>(active_medium)) {
                // volpathlocal: tracked media by ratio tracking (below), the
                // others as volpath
                Mask tracked = tracked_lanes(medium, active_medium);
                Mask sampled = active_medium && !tracked;

                // volpathlocal: no collision of their own for tracked lanes
                // (not sampled: see the path loop)
                Float u = sampler->next_1d(active_medium);
                auto mei = dr::zeros<MediumInteraction3f>();
                if (dr::any_or<true>(sampled))
                    mei = medium->sample_interaction(ray, u, channel, sampled);
                dr::masked(mei.t, tracked) = dr::Infinity<Float>;
                dr::masked(ray.maxt, sampled && medium->is_homogeneous() && mei.is_valid()) = dr::minimum(mei.t, remaining_dist);
                Mask intersect = needs_intersection && active_medium;
                if (dr::any_or<true>(intersect))
                    dr::masked(si, intersect) = scene->ray_intersect(ray, intersect);

                dr::masked(mei.t, active_medium && (si.t < mei.t)) = dr::Infinity<Float>;
                needs_intersection &= !active_medium;

                // volpathlocal: (residual) ratio tracking the whole way to the
                // surface (or the emitter); the lane then leaves the medium there
                for (const TrackedMedium &k : m_tracked) {
                    Mask in_k = tracked && (medium == MediumPtr(k.medium));
                    if (dr::none_or<false>(in_k))
                        continue;
                    auto [tr, tripped_k] = Tracker::ratio_tracking(
                        k, ray, dr::minimum(si.t, remaining_dist), m_coarse_depth_var, sampler,
                        in_k, m_shadow_estimates, m_residual);
                    dr::masked(transmittance, in_k) *= tr;
                    dr::masked(ls.tripped, in_k) |= tripped_k;
                }

                Mask is_spectral = medium->has_spectral_extinction() && sampled;
                Mask not_spectral = !is_spectral && sampled;
                // volpathlocal: no collision and no surface before an emitter
                // at infinity is a weight of 1, as for the path
                Mask weighted = is_spectral && (mei.is_valid() || si.is_valid());
                if (dr::any_or<true>(weighted)) {
                    Float t      = dr::minimum(remaining_dist, dr::minimum(mei.t, si.t)) - mei.mint;
                    UnpolarizedSpectrum tr  = dr::exp(-t * mei.combined_extinction);
                    UnpolarizedSpectrum free_flight_pdf = dr::select(si.t < mei.t || mei.t > remaining_dist, tr, tr * mei.combined_extinction);
                    Float tr_pdf = index_spectrum(free_flight_pdf, channel);
                    // volpathlocal: weighted lanes (above)
                    dr::masked(transmittance, weighted) *= dr::select(tr_pdf > 0.f, tr / tr_pdf, 0.f);
                }

                // Handle exceeding the maximum distance by medium sampling
                dr::masked(total_dist, active_medium && (mei.t > remaining_dist) && mei.is_valid()) = dir_sample.dist;
                dr::masked(mei.t, active_medium && (mei.t > remaining_dist)) = dr::Infinity<Float>;

                escaped_medium = active_medium && !mei.is_valid();
                active_medium &= mei.is_valid();
                is_spectral &= active_medium;
                not_spectral &= active_medium;

                dr::masked(total_dist, active_medium) += mei.t;

                if (dr::any_or<true>(active_medium)) {
                    dr::masked(ray.o, active_medium)    = mei.p;
                    dr::masked(si.t, active_medium) = si.t - mei.t;

                    if (dr::any_or<true>(is_spectral))
                        dr::masked(transmittance, is_spectral) *= mei.sigma_n;
                    if (dr::any_or<true>(not_spectral))
                        dr::masked(transmittance, not_spectral) *= mei.sigma_n / mei.combined_extinction;
                }
            }

            // Handle interactions with surfaces
            Mask intersect = active_surface && needs_intersection;
            if (dr::any_or<true>(intersect))
                dr::masked(si, intersect)    = scene->ray_intersect(ray, intersect);
            needs_intersection &= !intersect;
            active_surface |= escaped_medium;
            dr::masked(total_dist, active_surface) += si.t;

            active_surface &= si.is_valid() && active && !active_medium;
            if (dr::any_or<true>(active_surface)) {
                auto bsdf         = si.bsdf(ray);
                Spectrum bsdf_val = bsdf->eval_null_transmission(si, active_surface);
                bsdf_val = si.to_world_mueller(bsdf_val, si.wi, si.wi);
                dr::masked(transmittance, active_surface) *= bsdf_val;
            }

            // Update the ray with new origin & t parameter
            dr::masked(ray, active_surface) = si.spawn_ray(ray.d);
            ray.maxt = remaining_dist;
            needs_intersection |= active_surface;

            // Continue tracing through scene if non-zero weights exist
            active &= (active_medium || active_surface) &&
                      dr::any(unpolarized_spectrum(transmittance) != 0.f);

            // If a medium transition is taking place: Update the medium pointer
            Mask has_medium_trans = active_surface && si.is_medium_transition();
            if (dr::any_or<true>(has_medium_trans)) {
                dr::masked(medium, has_medium_trans) = si.target_medium(ray.d);
            }

            // volpathlocal: the loop bound
            Trips::bound_loop(ShadowLoop, dr::any(ray.o != origin_before), active, ls.stalls,
                              ls.steps, ls.tripped);
        },
        "volpathlocal: emitter sampling");

        dr::masked(tripped, active) |= ls.tripped; // volpathlocal
        return { ls.transmittance, ls.medium }; // volpathlocal: (trace_shadow)
    }

    //! @}
    // =============================================================

    std::string to_string() const override {
        // volpathlocal: its own name, the tracking's settings, the loop bounds' trips
        m_trips.report();
        return tfm::format("VolumetricPathLocalMajorants[\n"
                           "  max_depth = %i,\n"
                           "  rr_depth = %i,\n" // volpathlocal: and the eight below
                           "  coarse_optical_depth = %f,\n"
                           "  transmittance = %s,\n"
                           "  emission_sampling = %s,\n"
                           "  emission_rate = %f,\n"
                           "  emission_samples = %u,\n"
                           "  max_majorant_ratio = %f,\n"
                           "  tracked media = %zu,\n"
                           "  loop bound trips = [%s]\n"
                           "]",
                           m_max_depth, m_rr_depth, m_coarse_depth, // volpathlocal
                           m_residual ? "residual" : "ratio",
                           m_emission_sampling == EmissionSampling::Mis ? "mis"
                           : m_emission_sampling == EmissionSampling::Nee ? "nee" : "collisions",
                           m_emission_rate, m_emission_samples, m_max_ratio,
                           m_tracked.size(), m_trips.list());
    }

    Float mis_weight(Float pdf_a, Float pdf_b) const {
        pdf_a *= pdf_a;
        pdf_b *= pdf_b;
        Float w = pdf_a / (pdf_a + pdf_b);
        return dr::select(dr::isfinite(w), w, 0.f);
    };

    MI_DECLARE_CLASS(VolumetricPathLocalMajorants)

private:
    // =====================================================================
    //  volpathlocal: the media to track (tracked_media.h)
    // =====================================================================

    /// Finds the media to track (tracked_media.h), on every render (a scale
    /// may have changed), and on the first sample() for a scene that
    /// render() did not see
    void prepare(const Scene *scene, bool force) const {
        if (!force && m_prepared_for.load(std::memory_order_acquire) == scene)
            return; // the common case: no lock per sample() call
        std::lock_guard<std::mutex> guard(m_prepare_mutex);
        if (!force && m_prepared_for.load(std::memory_order_relaxed) == scene)
            return;
        m_tracked = TrackedMedia<Float, Spectrum>::find(scene, m_max_ratio);
        // The emissive media next-event estimation samples, each chosen in
        // proportion to its emitted power
        double power = 0.0;
        m_nee_media = false;
        m_last_nee = 0;
        if (m_emission_sampling != EmissionSampling::Collisions)
            for (size_t i = 0; i < m_tracked.size(); ++i) {
                TrackedMedium &k = m_tracked[i];
                k.nee = k.emissive && k.emissive->prepare_emission_sampling();
                if (k.nee) {
                    power += k.emissive->emission_power();
                    m_last_nee = (uint32_t) i + 1;
                }
            }
        for (TrackedMedium &k : m_tracked)
            if (k.nee) {
                k.select = dr::opaque<Float>((ScalarFloat) (k.emissive->emission_power() / power));
                m_nee_media = true;
            }
        m_prepared_for.store(scene, std::memory_order_release);
    }

    /// The lanes of `active` whose medium is tracked
    Mask tracked_lanes(const MediumPtr &medium, const Mask &active) const {
        Mask tracked = false;
        for (const TrackedMedium &k : m_tracked)
            tracked |= active && (medium == MediumPtr(k.medium));
        return tracked;
    }

    // volpathlocal: the tracking's settings and state
    ScalarFloat m_coarse_depth;
    Float m_coarse_depth_var; ///< the same, as a kernel parameter
    UInt32 m_max_depth_var, m_rr_depth_var; ///< max_depth and rr_depth, as kernel parameters
    ScalarFloat m_max_ratio;
    uint32_t m_shadow_estimates; ///< ratio-tracking estimates a shadow ray averages
    uint32_t m_emission_samples = 1; ///< next-event estimates toward emissive media per vertex
    bool m_residual;             ///< shadow rays: residual ratio tracking (else ratio tracking)
    /// Emissive media: emission by collisions only, or also by next-event
    /// estimation with MIS, or (tests) by next-event estimation alone where
    /// it applies
    enum class EmissionSampling { Mis, Collisions, Nee } m_emission_sampling = EmissionSampling::Mis;
    ScalarFloat m_emission_rate = 1.f; ///< the camera segment's extra samples per voxel
    mutable bool m_nee_media = false;  ///< prepare(): some medium is sampled
    mutable uint32_t m_last_nee = 0;   ///< ... the last one is m_tracked[m_last_nee - 1]
    mutable std::vector<TrackedMedium> m_tracked;
    mutable std::atomic<const Scene *> m_prepared_for{ nullptr };
    mutable std::mutex m_prepare_mutex;
    LoopTrips<Float> m_trips; ///< the lanes each loop bound stopped (loop_bounds.h)
    uint32_t m_trip_total_host = 0, m_tracked_host = 0; ///< traverse()'s copies

    MI_TRAVERSE_CB(Base, m_coarse_depth_var, m_max_depth_var, m_rr_depth_var, m_trips.jit_counts)
};

MI_EXPORT_PLUGIN(VolumetricPathLocalMajorants) // volpathlocal: its own name
NAMESPACE_END(mitsuba)
