from __future__ import annotations # Delayed parsing of type annotations

import drjit as dr
import mitsuba as mi

# prbvolpathlocal: the upstream module's imports, absolute; the walk bridge
from mitsuba.ad.integrators.common import RBIntegrator, mis_weight

from .walk_bridge import WalkBridge, medium_index

def index_spectrum(spec, idx):
    m = spec[0]
    if mi.is_rgb:
        m[idx == 1] = spec[1]
        m[idx == 2] = spec[2]
    return m

# prbvolpathlocal: its own name and documentation
class PRBVolpathLocalIntegrator(RBIntegrator):
    r"""
    .. _integrator-prbvolpathlocal:

    Path Replay Backpropagation through local majorants (:monosp:`prbvolpathlocal`)
    -------------------------------------------------------------------------------

    .. pluginparameters::

     * - max_depth
       - |int|
       - Specifies the longest path depth in the generated output image (where -1
         corresponds to :math:`\infty`). A value of 1 will only render directly
         visible light sources. 2 will lead to single-bounce (direct-only)
         illumination, and so on. (Default: 6)

     * - rr_depth
       - |int|
       - Specifies the path depth, at which the implementation will begin to use
         the *russian roulette* path termination criterion. For example, if set to
         1, then path generation many randomly cease after encountering directly
         visible surfaces. (Default: 5)

     * - hide_emitters
       - |bool|
       - Hide directly visible emitters. (Default: no, i.e. |false|)

     * - max_majorant_ratio
       - |float|
       - As ``volpathlocal``'s: a ``nanovdbvolume`` medium is tracked through
         its local majorants only if they average at most this fraction of
         its global majorant; above it, it takes ``prbvolpath``'s path.
         (Default: 0.5)

     * - coarse_optical_depth
       - |float|
       - As ``volpathlocal``'s: internal nodes whose majorant gives at most
         this optical depth along any chord are crossed as one segment.
         (Default: 2)

     * - majorant_headroom
       - |float|
       - Free flights use the walk's majorants times this factor (at least
         1). Differential delta tracking learns a value's derivative from
         the null collisions, with weight :math:`1/\mu_n`: where the
         density reaches its majorant (:math:`\mu_n = 0`, a node of one
         value, as in a volume that starts constant) no null collision
         happens and the derivative is lost, and near it the weights'
         variance is large. ``prbvolpath`` has this at its one global
         maximum (hence the advice to give ``max_value`` headroom); local
         majorants reach every node's maximum, so the headroom is built in:
         at 2, at least half the tentative collisions are null. 1 is the
         tight walk. (Default: 2)

     * - transmittance_headroom
       - |float|
       - The same factor for shadow rays (at least 1). Ratio tracking's
         derivative weighs each tentative collision by
         :math:`1/\bar\mu`, not :math:`1/\mu_n`, so the tight walk keeps it
         (a factor of exactly 0 would end the walk and lose it; the walk's
         bounds sit :math:`2^{-20}` above the values); a larger factor
         lowers the derivative's variance at the price of more lookups.
         (Default: 1)

    Mitsuba 3.9.1's ``prbvolpath`` (``python/ad/integrators/prbvolpath.py``,
    BSD-3-Clause), its structure, names and comments, with each difference
    marked ``# prbvolpathlocal:``. Registered in every ``*_ad_*`` variant
    (except the polarized ones) once ``nanovdb_mitsuba`` is imported.

    A medium that ``volpathlocal`` tracks (``heterogeneous`` or
    ``emissiveheterogeneous`` over a ``nanovdbvolume``) is tracked here
    through the same walk of its tree's local majorants, in the primal and
    the adjoint pass alike (src/integrators/walk_bridge.cpp): tentative
    collisions come at the rate of the walk's majorant where the ray is,
    not of the global one, so empty and thin space costs no lookups. The
    estimators are ``prbvolpath``'s with that majorant: differential delta
    tracking for free flights (each null collision's weight
    :math:`\mu_n / \mu_n` and real collision's :math:`\mu_s / \mu_t`
    attached, the majorant detached) and differential ratio tracking for
    shadow rays. An emissive medium adds :math:`\sigma_a L_e / \bar\mu`
    at every tentative collision (pbrt-v4's estimator, ``volpathlocal``'s
    ``collisions``), attached to its emission grid. A free flight and a
    shadow ray's transmittance are each one call and one walk, their
    adjoints backpropagated inside it (``prbvolpath`` spends a loop
    iteration per tentative collision); their random numbers come from a
    PCG32 that the path's sampler seeds, so the adjoint pass replays them.
    Every other medium takes ``prbvolpath``'s path. Sensors inside media
    are not supported, as in ``prbvolpath``. Guide: docs/differentiable.md.

    .. tabs::
        .. code-tab:: xml

            <integrator type="prbvolpathlocal">
                <integer name="max_depth" value="8"/>
            </integrator>

        .. code-tab:: python

            'type': 'prbvolpathlocal',
            'max_depth': 8
        """
    def __init__(self, props):
        super().__init__(props)
        # prbvolpathlocal: the walk's settings (volpathlocal's) and the
        # tracked media of the scene last prepared
        self.coarse_depth = props.get("coarse_optical_depth", 2.0)
        self.max_ratio = props.get("max_majorant_ratio", 0.5)
        self.headroom = props.get("majorant_headroom", 2.0)
        self.transmittance_headroom = props.get("transmittance_headroom", 1.0)
        for name, h in (("majorant_headroom", self.headroom),
                        ("transmittance_headroom", self.transmittance_headroom)):
            if not (h >= 1 and h < float("inf")):
                raise ValueError(f"prbvolpathlocal: {name} must be a finite value >= 1, got {h}")
        if not (self.coarse_depth >= 0 and self.coarse_depth < float("inf")):
            raise ValueError("prbvolpathlocal: coarse_optical_depth must be a finite value "
                             f">= 0, got {self.coarse_depth}")
        if not (0 <= self.max_ratio <= 1):
            raise ValueError(f"prbvolpathlocal: max_majorant_ratio must be in [0, 1], got "
                             f"{self.max_ratio}")
        self.bridge = WalkBridge.for_variant()
        self.tracked = []
        self.prepared_for = None
        self.use_nee = False
        self.nee_handle_homogeneous = False
        self.handle_null_scattering = False
        self.is_prepared = False

    def prepare_scene(self, scene):
        # prbvolpathlocal: prepared per scene and media (upstream: once).
        # The scene is remembered by its id and its media's, not held: Dr.Jit's
        # traversal of the integrator (dr.freeze) would recurse through it
        media = [m for shape in scene.shapes()
                 for m in (shape.interior_medium(), shape.exterior_medium())]
        key = (id(scene), tuple(medium_index(m) for m in media if m is not None))
        if self.is_prepared and self.prepared_for == key:
            return
        # prbvolpathlocal: the tracked media (as volpathlocal finds them)
        self.tracked = []
        seen = set()
        # (the shapes' media only: paths start outside media here, as upstream)
        for m in media:
            if m is None or medium_index(m) in seen:
                continue
            seen.add(medium_index(m))
            if self.bridge.tracked(m, self.max_ratio):  # (2: it emits; fly() sees to that)
                self.tracked.append((m, medium_index(m)))
        self.prepared_for = key

        for shape in scene.shapes():
            for medium in [shape.interior_medium(), shape.exterior_medium()]:
                if medium is not None:
                    # Enable NEE if a medium specifically asks for it
                    self.use_nee = self.use_nee or medium.use_emitter_sampling()
                    self.nee_handle_homogeneous = self.nee_handle_homogeneous or medium.is_homogeneous()
                    self.handle_null_scattering = self.handle_null_scattering or (not medium.is_homogeneous())
        self.is_prepared = True
        # By default enable always NEE in case there are surfaces
        self.use_nee = True

    @dr.syntax
    def sample(self,
               mode: dr.ADMode,
               scene: mi.Scene,
               sampler: mi.Sampler,
               ray: mi.Ray3f,
               δL: Optional[mi.Spectrum],
               state_in: Optional[mi.Spectrum],
               active: mi.Bool,
               **kwargs # Absorbs unused arguments
    ) -> Tuple[mi.Spectrum, mi.Bool, List[mi.Float], mi.Spectrum]:
        self.prepare_scene(scene)

        if mode == dr.ADMode.Forward:
            raise RuntimeError("PRBVolpathIntegrator doesn't support "
                               "forward-mode differentiation!")

        is_primal = mode == dr.ADMode.Primal

        ray = mi.Ray3f(ray)
        depth = mi.UInt32(0)                          # Depth of current vertex
        L = mi.Spectrum(0 if is_primal else state_in) # Radiance accumulator
        δL = mi.Spectrum(δL if δL is not None else 0) # Differential/adjoint radiance
        throughput = mi.Spectrum(1)                   # Path throughput weight
        η = mi.Float(1)                               # Index of refraction
        active = mi.Bool(active)

        si = dr.zeros(mi.SurfaceInteraction3f)
        needs_intersection = mi.Bool(True)
        last_scatter_event = dr.zeros(mi.Interaction3f)
        last_scatter_direction_pdf = mi.Float(1.0)

        # TODO: support sensors inside media
        medium = dr.zeros(mi.MediumPtr)

        channel = 0
        depth = mi.UInt32(0)
        valid_ray = mi.Bool(False)
        specular_chain = mi.Bool(True)

        if mi.is_rgb:
            # Sample a color channel to sample free-flight distances
            n_channels = dr.size_v(mi.Spectrum)
            channel = mi.UInt32(dr.minimum(n_channels * sampler.next_1d(active), n_channels - 1))

        while dr.hint(active,
                      label=f"Path Replay Backpropagation ({mode.name})"):
            active &= dr.any(throughput != 0.0)

            #--------------------- Perform russian roulette --------------------

            q = dr.minimum(dr.max(throughput) * dr.square(η), 0.99)
            perform_rr = (depth > self.rr_depth)
            active &= (sampler.next_1d(active) < q) | ~perform_rr
            throughput[perform_rr] = throughput * dr.rcp(q)

            active_medium = active & (medium != None)
            active_surface = active & ~active_medium

            with dr.resume_grad(when=not is_primal):
                #--------------------- Sample medium interaction -------------------

                # Handle medium sampling and potential medium escape
                u = sampler.next_1d(active_medium)
                # prbvolpathlocal: the lanes in a tracked medium sample
                # theirs through its walk, below (a masked call returns zeros)
                tracked = self.tracked_lanes(medium, active_medium)
                mei = medium.sample_interaction(ray, u, channel, active_medium & ~tracked)
                mei.t = dr.detach(mei.t)

                ray.maxt[active_medium & medium.is_homogeneous() & mei.is_valid()] = mei.t
                intersect = needs_intersection & active_medium
                si[intersect] = scene.ray_intersect(ray, intersect)

                needs_intersection &= ~active_medium
                # prbvolpathlocal: the tracked lanes' whole free flight up to
                # the surface, in one call through the walk: its null
                # collisions, an emissive medium's emission at every
                # tentative collision and the real collision's weight, with
                # their adjoints (fly_tracked); mei becomes the real
                # collision (detached) or none
                if dr.hint(len(self.tracked) > 0, mode='scalar'):
                    throughput, L, flight = self.fly_tracked(
                        ray, dr.minimum(si.t, ray.maxt), medium, tracked, sampler, throughput, L,
                        δL, is_primal)
                    mei[tracked] = flight
                mei.t[active_medium & (si.t < mei.t)] = dr.inf

                # Evaluate ratio of transmittance and free-flight PDF
                # prbvolpathlocal: (the untracked lanes; a tracked lane's
                # weights are in its throughput already, here and below)
                tr, free_flight_pdf = medium.transmittance_eval_pdf(mei, si, active_medium & ~tracked)
                tr_pdf = index_spectrum(free_flight_pdf, channel)
                weight = mi.Spectrum(1.0)
                weight[active_medium & ~tracked] *= dr.select(tr_pdf > 0.0, tr / dr.detach(tr_pdf), 0.0)  # prbvolpathlocal

                escaped_medium = active_medium & ~mei.is_valid()
                active_medium &= mei.is_valid()

                # Handle null and real scatter events
                if dr.hint(self.handle_null_scattering, mode='scalar'):
                    scatter_prob = dr.mean(mei.sigma_t / mei.combined_extinction)
                    act_null_scatter = (sampler.next_1d(active_medium & ~tracked) >= scatter_prob) & active_medium & ~tracked  # prbvolpathlocal
                    act_medium_scatter = ~act_null_scatter & active_medium
                    weight[act_null_scatter] *= mei.sigma_n / dr.detach(1 - scatter_prob)
                else:
                    scatter_prob = mi.Float(1.0)
                    act_medium_scatter = active_medium

                depth[act_medium_scatter] += 1
                last_scatter_event[act_medium_scatter] = dr.detach(mei)

                # Don't estimate lighting if we exceeded number of bounces
                active &= depth < self.max_depth
                act_medium_scatter &= active
                if dr.hint(self.handle_null_scattering, mode='scalar'):
                    ray.o[act_null_scatter] = dr.detach(mei.p)
                    si.t[act_null_scatter] = si.t - dr.detach(mei.t)

                weight[act_medium_scatter & ~tracked] *= mei.sigma_s / dr.detach(scatter_prob)  # prbvolpathlocal
                throughput *= dr.detach(weight)

                mei = dr.detach(mei)
                if dr.hint(not is_primal and dr.grad_enabled(weight), mode='scalar'):
                    Lo = dr.detach(dr.select(active_medium | escaped_medium, L / dr.maximum(1e-8, weight), 0.0))
                    dr.backward(δL * weight * Lo)

                phase_ctx = mi.PhaseFunctionContext(sampler)
                phase = mei.medium.phase_function()
                phase[~act_medium_scatter] = dr.zeros(mi.PhaseFunctionPtr)

                #--------------------- Surface Interactions --------------------

                active_surface |= escaped_medium
                intersect = active_surface & needs_intersection
                si[intersect] = scene.ray_intersect(ray, intersect)

                # ---------------------- Hide area emitters ----------------------

                if dr.hint(self.hide_emitters, mode='scalar'):
                    # Are we on the first segment and did we hit an area emitter?
                    # If so, skip all area emitters along this ray
                    skip_emitters = (
                        si.is_valid() &
                        (si.shape.emitter() != None) &
                        (depth == 0) &
                        intersect
                    )

                    ray_skip = si.spawn_ray(ray.d)
                    pi = self.skip_area_emitters(scene, ray_skip, True, skip_emitters)
                    si_after_skip = pi.compute_surface_interaction(ray, mi.RayFlags.All, skip_emitters)
                    si[skip_emitters] = si_after_skip

                # ----------------- Intersection with emitters -----------------

                ray_from_camera = active_surface & (depth == 0)
                count_direct = ray_from_camera | specular_chain
                emitter = si.emitter(scene)
                active_e = active_surface & (emitter != None) & ~((depth == 0) & self.hide_emitters)

                # Get the PDF of sampling this emitter using next event estimation
                ds = mi.DirectionSample3f(scene, si, last_scatter_event)
                if dr.hint(self.use_nee, mode='scalar'):
                    emitter_pdf = scene.pdf_emitter_direction(last_scatter_event, ds, active_e)
                else:
                    emitter_pdf = 0.0
                emitted = emitter.eval(si, active_e)
                contrib = dr.select(count_direct, throughput * emitted,
                                    throughput * mis_weight(last_scatter_direction_pdf, emitter_pdf) * emitted)
                L[active_e] += dr.detach(contrib if is_primal else -contrib)
                if dr.hint(not is_primal and dr.grad_enabled(contrib), mode='scalar'):
                    dr.backward(δL * contrib)

                active_surface &= si.is_valid()
                ctx = mi.BSDFContext()
                bsdf = si.bsdf(ray)

                # ---------------------- Emitter sampling ----------------------

                if dr.hint(self.use_nee, mode='scalar'):
                    active_e_surface = active_surface & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth) & (depth + 1 < self.max_depth)
                    sample_emitters = mei.medium.use_emitter_sampling()
                    specular_chain &= ~act_medium_scatter
                    specular_chain |= act_medium_scatter & ~sample_emitters

                    active_e_medium = act_medium_scatter & sample_emitters
                    active_e = active_e_surface | active_e_medium

                    nee_sampler = sampler if is_primal else sampler.clone()
                    emitted, ds = self.sample_emitter(mei, si, active_e_medium, active_e_surface,
                        scene, sampler, medium, channel, active_e, mode=dr.ADMode.Primal)

                    # Query the BSDF for that emitter-sampled direction
                    bsdf_val, bsdf_pdf = bsdf.eval_pdf(ctx, si, si.to_local(ds.d), active_e_surface)
                    phase_val, phase_pdf = phase.eval_pdf(phase_ctx, mei, ds.d, active_e_medium)
                    nee_weight = dr.select(active_e_surface, bsdf_val, phase_val)
                    nee_directional_pdf = dr.select(ds.delta, 0.0, dr.select(active_e_surface, bsdf_pdf, phase_pdf))

                    contrib = throughput * nee_weight * mis_weight(ds.pdf, nee_directional_pdf) * emitted
                    L[active_e] += dr.detach(contrib if is_primal else -contrib)

                    if dr.hint(not is_primal, mode='scalar'):
                        self.sample_emitter(mei, si, active_e_medium, active_e_surface,
                            scene, nee_sampler, medium, channel, active_e, adj_emitted=contrib,
                            δL=δL, mode=mode)

                        if dr.hint(dr.grad_enabled(nee_weight) or dr.grad_enabled(emitted), mode='scalar'):
                            dr.backward(δL * contrib)

                #-------------------- Phase function sampling ------------------

                valid_ray |= act_medium_scatter
                with dr.suspend_grad():
                    wo, phase_weight, phase_pdf = phase.sample(phase_ctx, mei,
                                                               sampler.next_1d(act_medium_scatter),
                                                               sampler.next_2d(act_medium_scatter),
                                                               act_medium_scatter)
                act_medium_scatter &= phase_pdf > 0.0

                # Re evaluate the phase function value in an attached manner
                phase_eval, _ = phase.eval_pdf(phase_ctx, mei, wo, act_medium_scatter)
                if dr.hint(not is_primal and dr.grad_enabled(phase_eval), mode='scalar'):
                    Lo = phase_eval * dr.detach(dr.select(act_medium_scatter, L / dr.maximum(1e-8, phase_eval), 0.0))
                    if mode == dr.ADMode.Backward:
                        dr.backward_from(δL * Lo)
                    else:
                        δL += dr.forward_to(Lo)

                throughput[act_medium_scatter] *= phase_weight
                ray[act_medium_scatter] = mei.spawn_ray(wo)
                needs_intersection |= act_medium_scatter
                last_scatter_direction_pdf[act_medium_scatter] = phase_pdf

                # ------------------------ BSDF sampling -----------------------

                with dr.suspend_grad():
                    bs, bsdf_weight = bsdf.sample(ctx, si,
                                                  sampler.next_1d(active_surface),
                                                  sampler.next_2d(active_surface),
                                                  active_surface)
                    active_surface &= bs.pdf > 0

                bsdf_eval = bsdf.eval(ctx, si, bs.wo, active_surface)

                if dr.hint(not is_primal and dr.grad_enabled(bsdf_eval), mode='scalar'):
                    Lo = bsdf_eval * dr.detach(dr.select(active_surface, L / dr.maximum(1e-8, bsdf_eval), 0.0))
                    if dr.hint(mode == dr.ADMode.Backward, mode='scalar'):
                        dr.backward_from(δL * Lo)
                    else:
                        δL += dr.forward_to(Lo)

                throughput[active_surface] *= bsdf_weight
                η[active_surface] *= bs.eta
                bsdf_ray = si.spawn_ray(si.to_world(bs.wo))
                ray[active_surface] = bsdf_ray

                needs_intersection |= active_surface
                non_null_bsdf = active_surface & ~mi.has_flag(bs.sampled_type, mi.BSDFFlags.Null)
                depth[non_null_bsdf] += 1

                # update the last scatter PDF event if we encountered a non-null scatter event
                last_scatter_event[non_null_bsdf] = si
                last_scatter_direction_pdf[non_null_bsdf] = bs.pdf

                valid_ray |= non_null_bsdf
                specular_chain |= non_null_bsdf & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
                specular_chain &= ~(active_surface & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Smooth))
                has_medium_trans = active_surface & si.is_medium_transition()
                medium[has_medium_trans] = si.target_medium(ray.d)
                active &= (active_surface | active_medium)

        return L if is_primal else δL, valid_ray, [], L

    @dr.syntax
    def sample_emitter(self, mei, si, active_medium, active_surface, scene, sampler, medium, channel,
                       active, adj_emitted=None, δL=None, mode=None):
        is_primal = mode == dr.ADMode.Primal

        active = mi.Bool(active)

        ref_interaction = dr.zeros(mi.Interaction3f)
        ref_interaction[active_medium] = mei
        ref_interaction[active_surface] = si

        ds, emitter_val = scene.sample_emitter_direction(ref_interaction,
                                                         sampler.next_2d(active),
                                                         False, active)
        ds = dr.detach(ds)
        invalid = (ds.pdf == 0.0)
        emitter_val[invalid] = 0.0
        active &= ~invalid

        medium = dr.select(active, medium, dr.zeros(mi.MediumPtr))
        medium[(active_surface & si.is_medium_transition())] = si.target_medium(ds.d)

        ray = ref_interaction.spawn_ray_to(ds.p)
        max_dist = mi.Float(ray.maxt)
        total_dist = mi.Float(0.0)
        si = dr.zeros(mi.SurfaceInteraction3f)
        needs_intersection = mi.Bool(True)
        transmittance = mi.Spectrum(1.0)

        while dr.hint(active, label=f"PRB Next Event Estimation ({mode.name})"):
            remaining_dist = max_dist - total_dist
            ray.maxt = dr.detach(remaining_dist)
            active &= remaining_dist > 0.0

            # This ray will not intersect if it reached the end of the segment
            needs_intersection &= active
            si[needs_intersection] = scene.ray_intersect(ray, needs_intersection)
            needs_intersection &= False

            active_medium = active & (medium != None)
            active_surface = active & ~active_medium

            # Handle medium interactions / transmittance
            # prbvolpathlocal: the tracked lanes' through the walk (as above)
            u = sampler.next_1d(active_medium)
            tracked = self.tracked_lanes(medium, active_medium)
            mei = medium.sample_interaction(ray, u, channel, active_medium & ~tracked)
            # prbvolpathlocal: a tracked lane's transmittance up to the
            # surface in one call through the walk, with its adjoint
            # (transmit_tracked); the lane then leaves the medium there
            if dr.hint(len(self.tracked) > 0, mode='scalar'):
                tr_tracked = self.transmit_tracked(
                    ray, dr.minimum(si.t, ray.maxt), medium, tracked, sampler,
                    None if is_primal else δL * adj_emitted, is_primal)
                mei.t[tracked] = dr.inf
            mei.t[active_medium & (si.t < mei.t)] = dr.inf
            mei.t = dr.detach(mei.t)

            tr_multiplier = mi.Spectrum(1.0)

            # Special case for homogeneous media: directly advance to the next surface / end of the segment
            if dr.hint(self.nee_handle_homogeneous, mode='scalar'):
                active_homogeneous = active_medium & medium.is_homogeneous()
                mei.t[active_homogeneous] = dr.minimum(remaining_dist, si.t)
                tr_multiplier[active_homogeneous] = medium.transmittance_eval_pdf(mei, si, active_homogeneous)[0]
                mei.t[active_homogeneous] = dr.inf

            if dr.hint(len(self.tracked) > 0, mode='scalar'):
                tr_multiplier[tracked] = tr_tracked  # prbvolpathlocal
            escaped_medium = active_medium & ~mei.is_valid()

            # Ratio tracking transmittance computation
            active_medium &= mei.is_valid()
            ray.o[active_medium] = dr.detach(mei.p)
            si.t[active_medium] = dr.detach(si.t - mei.t)
            tr_multiplier[active_medium] *= mei.sigma_n / mei.combined_extinction


            # Handle interactions with surfaces
            active_surface |= escaped_medium
            active_surface &= si.is_valid() & ~active_medium
            bsdf = si.bsdf(ray)
            bsdf_val = bsdf.eval_null_transmission(si, active_surface)
            tr_multiplier[active_surface] *= bsdf_val

            if dr.hint(not is_primal and dr.grad_enabled(tr_multiplier), mode='scalar'):
                active_adj = (active_surface | active_medium) & (tr_multiplier > 0.0)
                dr.backward(tr_multiplier * dr.detach(dr.select(active_adj, δL * adj_emitted / tr_multiplier, 0.0)))

            transmittance *= dr.detach(tr_multiplier)

            # Update the ray with new origin & t parameter
            ray[active_surface] = dr.detach(si.spawn_ray(mi.Vector3f(ray.d)))
            ray.maxt = dr.detach(remaining_dist)
            needs_intersection |= active_surface

            # Continue tracing through scene if non-zero weights exist
            active &= (active_medium | active_surface) & dr.any(transmittance != 0.0)
            total_dist[active] += dr.select(active_medium, mei.t, si.t)

            # If a medium transition is taking place: Update the medium pointer
            has_medium_trans = active_surface & si.is_medium_transition()
            medium[has_medium_trans] = si.target_medium(ray.d)

        return emitter_val * dr.detach(transmittance), ds

    # prbvolpathlocal: the tracked media's lanes, free flights and shadow rays
    def tracked_lanes(self, medium, active):
        """The lanes of `active` in a tracked medium"""
        lanes = mi.Bool(False)
        for m, _ in self.tracked:
            lanes |= active & (medium == mi.MediumPtr(m))
        return lanes

    def seed(self, sampler, active):
        """PCG32's state for the bridge's walk of a lane (fly(),
        transmit()), from two of the sampler's numbers (24 bits each), so
        that the adjoint pass, whose sampler replays the primal pass's,
        replays the walk"""
        bits = dr.reinterpret_array(mi.UInt32, sampler.next_1d(active))
        return bits ^ (dr.reinterpret_array(mi.UInt32, sampler.next_1d(active)) << 9)

    def transmit_tracked(self, ray, tmax, medium, tracked, sampler, w, is_primal):
        """The transmittance of the `tracked` lanes' shadow rays up to tmax:
        differential ratio tracking through the walk, in one bridge call
        (walk_bridge.cpp's transmit(): its tentative collisions at the
        walk's majorants times transmittance_headroom, and in the adjoint
        pass each factor's derivative backpropagated with weight w /
        factor, w = dL x the contribution). 1 elsewhere"""
        seed = self.seed(sampler, tracked)
        w = mi.Spectrum(0.0) if w is None else w
        tr = mi.Spectrum(1.0)
        for m, index in self.tracked:
            in_k = tracked & (medium == mi.MediumPtr(m))
            tr[in_k] = self.bridge.transmit(index, ray, tmax, seed, w, in_k, is_primal,
                                            self.coarse_depth, self.transmittance_headroom)
        return tr

    def fly_tracked(self, ray, tmax, medium, tracked, sampler, throughput, L, δL, is_primal):
        """The free flight of the `tracked` lanes up to tmax: differential
        delta tracking through the walk, the whole flight in one bridge
        call (walk_bridge.cpp's fly(): each tentative collision's emission,
        the null collisions' weights and the real one's, with their
        adjoints in the adjoint pass), its random numbers seeded from the
        sampler. Returns the throughput and L after it, and the real
        collision's interaction (detached; t infinite where the flight left
        the medium or reached tmax). Untracked lanes pass through unchanged."""
        seed = self.seed(sampler, tracked)
        mei = dr.zeros(mi.MediumInteraction3f)
        mei.t = mi.Float(dr.inf)
        throughput, L = mi.Spectrum(throughput), mi.Spectrum(L)
        for m, index in self.tracked:
            in_k = tracked & (medium == mi.MediumPtr(m))
            t, majorant, sigma_s, sigma_t, throughput_k, L_k = self.bridge.fly(
                index, ray, tmax, seed, throughput, L, δL, in_k, is_primal, self.coarse_depth,
                self.headroom)
            throughput[in_k] = throughput_k
            L[in_k] = L_k
            hit = in_k & dr.isfinite(t)
            k = dr.zeros(mi.MediumInteraction3f)
            k.t = t
            k.p = ray(dr.select(hit, t, 0.0))
            k.wi = -ray.d
            k.sh_frame = mi.Frame3f(k.wi)
            k.time = ray.time
            k.wavelengths = ray.wavelengths
            k.medium = mi.MediumPtr(m)
            k.combined_extinction = mi.UnpolarizedSpectrum(majorant)
            k.sigma_s = sigma_s
            k.sigma_t = sigma_t
            k.sigma_n = k.combined_extinction - sigma_t
            mei[in_k] = k
        return throughput, L, mei

    def to_string(self):
        return f'PRBVolpathLocalIntegrator[max_depth = {self.max_depth}]'  # prbvolpathlocal: its name


# prbvolpathlocal: registered by nanovdb_mitsuba (setup()), per variant
def register():
    """Registers prbvolpathlocal in the current variant (an *_ad_* one)"""
    mi.register_integrator("prbvolpathlocal", lambda props: PRBVolpathLocalIntegrator(props))
