/*
    nanovdb_mitsuba/emissive_medium.h -- what an emissive medium offers an
    integrator that renders its emission

    Mitsuba 3's Medium has no emission: its integrators (volpath, prbvolpath,
    volpathmis) add radiance only at emitters. A medium that implements this
    interface (emissiveheterogeneous, src/media/emissiveheterogeneous.cpp) emits
    sigma_a(x) Le(x) per unit length, sigma_a = sigma_t - sigma_s (pbrt-v4's
    convention: what does not absorb does not emit), and an integrator
    (volpathlocal) adds it along its tracked flights (src/integrators/
    tracking.h). The integrator finds the interface by dynamic_cast on the
    medium.
*/

#pragma once

#include <mitsuba/render/fwd.h>
#include <mitsuba/render/interaction.h>

NAMESPACE_BEGIN(mitsuba)

template <typename Float, typename Spectrum> class EmissiveMedium {
public:
    MI_IMPORT_CORE_TYPES()
    using MediumInteraction3f = MediumInteraction<Float, Spectrum>;
    using UnpolarizedSpectrum = unpolarized_spectrum_t<Spectrum>;

    virtual ~EmissiveMedium() = default;

    /**
     * The emitted radiance Le at the interaction's point and wavelengths
     * (before sigma_a: the medium emits sigma_a Le per unit length), with
     * the medium's emission scale applied; 0 outside the emission volume.
     */
    virtual UnpolarizedSpectrum eval_emission(const MediumInteraction3f &mei,
                                              Mask active) const = 0;

    /**
     * An integrator that renders the emission says so before it traces the
     * medium. A medium that is asked for its majorant without this
     * (Medium::sample_interaction: volpath, prbvolpath, ...) warns once
     * that the emission is left out.
     */
    virtual void set_emission_rendered() const = 0;

    // ---- Next-event estimation (issue 35): the emission as a distribution
    //      of points (src/media/emission_distribution.h)

    /**
     * Builds the emission's sampling table if it has none for its current
     * values (host code: the integrator calls it before it renders).
     * Returns whether the medium can be sampled; where it cannot (zero
     * power, a grid whose leaves cannot be addressed, a volume that is not
     * a nanovdbvolume) the medium says why, once.
     */
    virtual bool prepare_emission_sampling() const = 0;

    /// What the table holds (the emitted power, in the units of its largest
    /// channel): chooses among several emissive media
    virtual double emission_power() const = 0;

    /**
     * A world point in proportion to what it emits (u and u3 uniform), and
     * its pdf per unit volume. Only after prepare_emission_sampling()
     * returned true.
     */
    virtual std::pair<Point3f, Float> sample_emission_point(const Float &u, const Point3f &u3,
                                                            Mask active) const = 0;

    /// The pdf per unit volume that sample_emission_point() gives p (0 where
    /// it never samples)
    virtual Float emission_point_pdf(const Point3f &p, Mask active) const = 0;
};

NAMESPACE_END(mitsuba)
