/*
    nanovdb_mitsuba/local_majorants.h -- what a volume offers a tracking
    integrator: its majorants along a ray, piece by piece

    Mitsuba's media sample free-flight distances against one global majorant
    (Medium::sample_interaction, which is not virtual). A volume that
    implements this interface (nanovdbvolume) can instead hand out a
    piecewise constant majorant along any ray, from the node structure of
    its grid (nanovdb_drjit/majorant_walk.h), and an integrator
    (src/integrators/volpathlocal.cpp) tracks against it. The integrator
    finds the interface by dynamic_cast on the medium's sigma_t volume.

    The walk works in the volume's index space; rays are given in world
    space and keep their parameter t, so segments are world-space distances
    along the ray as given. Segment bounds are bounds of eval_1() (the
    medium multiplies them by its scale).
*/

#pragma once

#include <mitsuba/core/ray.h>
#include <mitsuba/render/fwd.h>

#include <nanovdb_drjit/majorant_walk.h>

NAMESPACE_BEGIN(mitsuba)

template <typename Float, typename Spectrum> class LocalMajorants {
public:
    MI_IMPORT_CORE_TYPES()
    using Ray3f = Ray<Point<Float, 3>, Spectrum>;
    using Walk = nanovdb_drjit::MajorantWalk<Float>;

    /// A ray in the volume's index space (what the walk's steps need)
    struct WalkRay {
        Vector3f origin, direction;
        Float coarse_limit;
        DRJIT_STRUCT(WalkRay, origin, direction, coarse_limit)
    };

    virtual ~LocalMajorants() = default;

    /**
     * The mean over the volume of the walk's finest bounds, as a fraction
     * of max() (nanovdb_loader::mean_bound): near 1 the walk cannot save
     * null collisions (a volume of one density) and only costs its steps;
     * far below 1 it saves most of them. The integrator uses it to decide
     * whether tracking through the walk pays.
     */
    virtual ScalarFloat local_majorant_ratio() const = 0;

    /// The largest bound a segment of the walk can have (the volume's max()):
    /// with the medium's scale, it bounds the number of tentative collisions
    /// a tracking loop can meet along a ray (the integrator's loop bounds).
    /// A variable the volume holds (opaque), not a host number: a frozen
    /// function (dr.freeze) finds it among its inputs, so its replays
    /// read the bound of the values after an update, not the recorded one
    virtual Float majorant_bound() const = 0;

    /// Whether the volume's lookups use a stochastic filter (filter_type
    /// stochastic_*): they then take random offsets (set_lookup_offsets)
    virtual bool stochastic_lookups() const = 0;

    /**
     * Until the next call on this thread, the volume's stochastic lookups
     * use the offsets `u` (in [0, 1)^3, one per lane; nullptr: a hash of
     * the position, as eval() does on its own): the integrator draws them
     * from its sampler and sets them around its calls that evaluate the
     * medium (Volume::eval has no sampler argument). Other volumes of the
     * medium (albedo) keep their hash.
     */
    virtual void set_lookup_offsets(const Vector3f *u) const = 0;

    /**
     * The ray in index space. `thin_depth` (per unit of eval_1) sets which
     * nodes are crossed whole: those whose bound M makes the optical depth
     * of any chord through them at most thin_depth * M * chord length,
     * i.e. at most thin_depth * M / (world length of the chord). Pass
     * tau / scale for a medium of that scale, to cross whole the nodes whose
     * optical depth is at most tau; 0 walks every leaf.
     */
    virtual WalkRay walk_ray(const Ray3f &ray, const Float &thin_depth, Mask active) const = 0;

    /**
     * Starts the walk on [tmin, tmax] of the ray (see walk_ray). With
     * `controls`, each segment also has a control (the mean of its cell's
     * values) and a lower bound of its lookups, Walk::control and
     * Walk::minorant, 0 <= minorant <= control <= majorant (residual ratio
     * tracking); pass the same to walk_advance. Without, they stay 0 and
     * cost nothing.
     */
    virtual Walk walk_begin(const WalkRay &ray, const Float &tmin, const Float &tmax,
                            Mask active, bool controls = false) const = 0;

    /// To the next segment; false where the walk has ended
    virtual Mask walk_advance(Walk &walk, const WalkRay &ray, Mask active,
                              bool controls = false) const = 0;
};

NAMESPACE_END(mitsuba)
