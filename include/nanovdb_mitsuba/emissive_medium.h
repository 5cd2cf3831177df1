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
};

NAMESPACE_END(mitsuba)
