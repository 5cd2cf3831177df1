/*
    src/integrators/tracked_media.h -- which of a scene's media volpathlocal
    tracks through local majorants (tracking.h), and which it leaves to
    volpath's own tracking

    A medium is tracked when it exposes a sigma_t volume offering local
    majorants (nanovdb_mitsuba/local_majorants.h) and a scale, as
    heterogeneous does, and its own majorant is scale x that volume's max()
    (so that scale x a segment's bound is a majorant of its extinction, as
    its global one is). An emissive medium (emissive_medium.h) is always
    tracked: its emission is added there. A volume of (nearly) one density,
    whose local majorants average more than max_majorant_ratio of the global
    one, is left to volpath's tracking: the walk would cost its steps and
    save no null collisions.
*/

#pragma once

#include <mitsuba/core/logger.h>
#include <mitsuba/render/emitter.h>
#include <mitsuba/render/medium.h>
#include <mitsuba/render/scene.h>
#include <mitsuba/render/sensor.h>
#include <mitsuba/render/shape.h>
#include <mitsuba/render/volume.h>

#include <nanovdb_mitsuba/emissive_medium.h>
#include <nanovdb_mitsuba/local_majorants.h>

#include "loop_bounds.h"
#include "tracking.h"

#include <algorithm>
#include <cmath>
#include <typeinfo>
#include <vector>

NAMESPACE_BEGIN(mitsuba)

template <typename Float, typename Spectrum> struct TrackedMedia {
    MI_IMPORT_TYPES(Scene, Medium, Volume)
    using TrackedMedium = typename Tracking<Float, Spectrum>::TrackedMedium;
    using Majorants = LocalMajorants<Float, Spectrum>;
    using Emissive = EmissiveMedium<Float, Spectrum>;

    /// Every medium of the scene (on shapes, sensors, emitters) that is
    /// tracked through its volume's local majorants
    static std::vector<TrackedMedium> find(const Scene *scene, ScalarFloat max_ratio) {
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
        std::vector<TrackedMedium> tracked;
        for (const Medium *m : media) {
            TrackedMedium k;
            if (track(m, max_ratio, k))
                tracked.push_back(k);
        }
        Log(Debug, "volpathlocal: %zu of %zu media tracked through local majorants",
            tracked.size(), media.size());
        return tracked;
    }

    /**
     * Whether medium m is tracked through its volume's local majorants
     * (find()'s rule), and then k: what tracking needs of it. `checked`:
     * the rule was applied before (walk_bridge.cpp, once per scene), so the
     * majorant check, which evaluates a kernel, is left out
     */
    static bool track(const Medium *m, ScalarFloat max_ratio, TrackedMedium &k,
                      bool checked = false) {
        FindParameters p;
        const_cast<Medium *>(m)->traverse(&p);
        const Majorants *v = p.sigma_t ? dynamic_cast<const Majorants *>(p.sigma_t) : nullptr;
        const Volume *volume = p.sigma_t ? dynamic_cast<const Volume *>(p.sigma_t) : nullptr;
        // (scale 0: nothing to track, and no collision either way)
        if (!v || !volume || !p.has_scale || !(p.scale > 0.f))
            return false;
        // An emissive medium is always tracked, where its emission is
        // added; its majorant is scale x max() by construction. (Not
        // tracked, e.g. its sigma_t not a nanovdbvolume: the medium
        // warns that its emission is left out)
        if (const Emissive *e = dynamic_cast<const Emissive *>(m)) {
            e->set_emission_rendered();
            k = medium(m, v, p.scale, e);
            return true;
        }
        // (the check evaluates a kernel: not while a frozen function records)
        if (!checked && !recording_frozen_function<Float>() &&
            !majorant_is_scale_times_max(m, p.scale * volume->max())) {
            Log(Debug, "volpathlocal: a medium's majorant is not scale x max(): "
                       "tracked as volpath does");
            return false;
        }
        if (v->local_majorant_ratio() > max_ratio) {
            Log(Debug, "volpathlocal: local majorants average %.2f of the global one "
                       "(above max_majorant_ratio = %.2f): tracked as volpath does",
                v->local_majorant_ratio(), max_ratio);
            return false;
        }
        k = medium(m, v, p.scale, nullptr);
        return true;
    }

private:
    /// Its scale and majorant as opaque variables (kernel parameters)
    static TrackedMedium medium(const Medium *m, const Majorants *v, ScalarFloat scale,
                                const Emissive *e) {
        Float scale_var = dr::opaque<Float>(scale);
        return { m, v, scale_var, scale_var * v->majorant_bound(),
                 v->stochastic_lookups(), e };
    }

    /// Reads what a medium exposes: "sigma_t" and "scale" (as heterogeneous)
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

    /// Whether a medium's majorant (at any point: heterogeneous media have
    /// one) is `expected` in every channel, to float rounding
    static bool majorant_is_scale_times_max(const Medium *m, ScalarFloat expected) {
        if constexpr (dr::is_jit_v<Float>) {
            MediumInteraction3f mei = dr::zeros<MediumInteraction3f>(1);
            UnpolarizedSpectrum maj = m->get_majorant(mei, true);
            dr::eval(maj);
            for (size_t c = 0; c < dr::size_v<UnpolarizedSpectrum>; ++c) {
                float value = dr::slice(maj[c], 0);
                if (!(std::abs(value - expected) <= 1e-5f * std::abs(expected)))
                    return false;
            }
        } else {
            MediumInteraction3f mei = dr::zeros<MediumInteraction3f>();
            UnpolarizedSpectrum maj = m->get_majorant(mei, true);
            for (size_t c = 0; c < dr::size_v<UnpolarizedSpectrum>; ++c)
                if (!(std::abs(maj[c] - expected) <= 1e-5f * std::abs(expected)))
                    return false;
        }
        return true;
    }
};

NAMESPACE_END(mitsuba)
