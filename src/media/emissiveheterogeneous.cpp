#include <mitsuba/core/plugin.h>
#include <mitsuba/core/properties.h>
#include <mitsuba/core/spectrum.h>
#include <mitsuba/core/string.h>
#include <mitsuba/render/interaction.h>
#include <mitsuba/render/medium.h>
#include <mitsuba/render/phase.h>
#include <mitsuba/render/texture.h>
#include <mitsuba/render/volume.h>

#include <nanovdb_mitsuba/blackbody.h>
#include <nanovdb_mitsuba/grid_units.h>
#include <nanovdb_mitsuba/emissive_medium.h>
#include <nanovdb_mitsuba/frozen.h>
#include <nanovdb_mitsuba/volume_source.h>
#include <nanovdb_mitsuba/plugin_variants.h>

#include "emission_distribution.h"

#include <atomic>
#include <cmath>
#include <memory>

NAMESPACE_BEGIN(mitsuba)

/**!

.. _medium-emissiveheterogeneous:

Emissive heterogeneous medium (:monosp:`emissiveheterogeneous`)
---------------------------------------------------------------

.. pluginparameters::

 * - albedo, sigma_t, scale, has_spectral_extinction, sample_emitters, (nested phase)
   - as :ref:`heterogeneous <medium-heterogeneous>`
   - The medium's absorption and scattering, exactly as ``heterogeneous``.
     A ``nanovdbvolume`` sigma_t is tracked through its local majorants by
     ``volpathlocal``. (Default: albedo 0.75, sigma_t 1, scale 1,
     has_spectral_extinction |true|, sample_emitters |true|, an
     ``isotropic`` phase)
   - |exposed| (albedo, sigma_t, scale), |differentiable| (albedo, sigma_t)

 * - emission
   - |float|, |volume|
   - Radiance mode: the emitted radiance, a one-channel volume (``flame``,
     ``heat``: times ``color``) or a three-channel one (a Vec3f grid: its
     colour, linear sRGB). Give this or ``temperature``.
   - |exposed|

 * - color
   - |spectrum|
   - Radiance mode, one-channel ``emission``: its colour, an emitter's
     spectrum (an RGB value becomes an illuminant in spectral variants, as
     an ``area`` emitter's radiance does). (Default: 1)
   - |exposed|

 * - temperature
   - |float|, |volume|
   - Temperature mode: a one-channel volume (``temperature``), mapped to
     kelvin as T = (value - ``temperature_offset``) x ``temperature_scale``;
     the emitted radiance is that of a blackbody at T: Mitsuba's
     ``blackbody`` spectrum (Planck's law, W m^-2 sr^-1 nm^-1) in spectral
     variants, its linear sRGB colour (mono: luminance) in the others.
     Nothing is emitted where T <= ``temperature_cutoff``.
   - |exposed|

 * - temperature_scale, temperature_offset
   - |float|
   - See ``temperature``: pbrt-v4's ``temperaturescale`` and
     ``temperatureoffset``. (Default: 1, 0)
   - |exposed|

 * - temperature_cutoff
   - |float|
   - Kelvin at or below which nothing is emitted (pbrt-v4: 100 K). (Default: 100)
   - |exposed|

 * - emission_scale
   - |float|
   - Multiplies the emitted radiance, either mode (pbrt-v4's ``Lescale``).
     (Default: 1)
   - |exposed|

A ``heterogeneous`` medium that also emits light, for fire and explosions:
per unit length it emits :math:`\sigma_a(x) L_e(x)`, with
:math:`\sigma_a = \sigma_t - \sigma_s = \sigma_t (1 - \text{albedo})` (as
pbrt-v4: a medium emits where it absorbs, so an emission grid needs a
density beside it). Along a ray of constant :math:`\sigma_a` and
:math:`L_e` through a slab of thickness :math:`d` with no scattering the
radiance is :math:`L_e (1 - e^{-\sigma_a d})`.

Only ``volpathlocal`` renders the emission, and only where ``sigma_t`` is a
``nanovdbvolume`` (the medium is then always tracked through its walk).
Mitsuba's own integrators (``volpath``, ``prbvolpath``, ...) render the
medium as ``heterogeneous`` without its emission, and the medium warns once
that they do.

Each volume is its own plugin, so density and emission can come from the
same file or from different ones, each placed by its own transform
(``use_grid_transform`` keeps grids of different index spaces aligned).
Emission outside the sigma_t volume's bounding box is not rendered.

.. tabs::
    .. code-tab:: xml

        <medium type="emissiveheterogeneous" id="fire">
            <volume name="sigma_t" type="nanovdbvolume">
                <string name="filename" value="explosion.nvdb"/>
                <string name="grid" value="density"/>
            </volume>
            <volume name="temperature" type="nanovdbvolume">
                <string name="filename" value="explosion.nvdb"/>
                <string name="grid" value="temperature"/>
            </volume>
            <float name="temperature_scale" value="1000"/>
            <float name="emission_scale" value="0.01"/>
            <float name="albedo" value="0.5"/>
            <float name="scale" value="20"/>
        </medium>

    .. code-tab:: python

        'fire': {
            'type': 'emissiveheterogeneous',
            'sigma_t': {'type': 'nanovdbvolume', 'filename': 'explosion.nvdb',
                        'grid': 'density'},
            'temperature': {'type': 'nanovdbvolume', 'filename': 'explosion.nvdb',
                            'grid': 'temperature'},
            'temperature_scale': 1000, 'emission_scale': 0.01,
            'albedo': 0.5, 'scale': 20,
        }
*/

// emissiveheterogeneous: heterogeneous's class under its own name, plus EmissiveMedium
template <typename Float, typename Spectrum>
class EmissiveHeterogeneousMedium final : public Medium<Float, Spectrum>,
                                          public EmissiveMedium<Float, Spectrum> {
public:
    // emissiveheterogeneous: the types it uses, the blackbody's, its own name
    MI_IMPORT_BASE(Medium, m_is_homogeneous, m_has_spectral_extinction, m_phase_function)
    MI_IMPORT_TYPES(Texture, Volume)
    using Blackbody = blackbody::BlackbodyColor<Float>;

    EmissiveHeterogeneousMedium(const Properties &props) : Base(props) {
        // As heterogeneous
        m_is_homogeneous = false;
        m_albedo = props.get_volume<Volume>("albedo", 0.75f);
        m_sigmat = props.get_volume<Volume>("sigma_t", 1.f); // emissiveheterogeneous: 1.f for 1.0f
        m_scale = props.get<ScalarFloat>("scale", 1.f);
        m_has_spectral_extinction = props.get<bool>("has_spectral_extinction", true);
        m_max_density = dr::opaque<Float>(m_scale * m_sigmat->max());
        // emissiveheterogeneous: the box kept opaque (update_bbox), then the emission
        update_bbox();

        // The emission: one of two modes
        const bool radiance = props.has_property("emission"),
                   temperature = props.has_property("temperature");
        if (radiance == temperature)
            Throw("emissiveheterogeneous: give exactly one of \"emission\" (a radiance "
                  "volume) or \"temperature\" (a temperature volume, blackbody radiance); "
                  "got %s", radiance ? "both" : "neither");
        m_emission_scale = props.get<ScalarFloat>("emission_scale", 1.f);
        if (!(std::isfinite(m_emission_scale) && m_emission_scale >= 0.f))
            Throw("emissiveheterogeneous: emission_scale must be finite and >= 0, got %f",
                  m_emission_scale);
        check_volume("sigma_t", m_sigmat.get(), false);
        if (radiance) {
            m_emission = props.get_volume<Volume>("emission");
            check_volume("emission", m_emission.get(), true);
            if (m_emission->channel_count() == 3) {
                if (props.has_property("color"))
                    Throw("emissiveheterogeneous: \"color\" multiplies a one-channel "
                          "emission volume; %s already has three (its colour)",
                          describe(m_emission.get()));
                // A spectral variant's upsampled colour is a reflectance:
                // times the D65 illuminant, as an emitter's RGB radiance
                if constexpr (is_spectral_v<Spectrum>)
                    m_d65 = PluginManager::instance()->create_object<Texture>(Properties("d65"));
            } else {
                m_color = props.get_emissive_texture<Texture>("color", 1.f);
            }
        } else { // emissiveheterogeneous: the temperature mode
            m_temperature = props.get_volume<Volume>("temperature");
            check_volume("temperature", m_temperature.get(), false);
            m_t_scale = props.get<ScalarFloat>("temperature_scale", 1.f);
            m_t_offset = props.get<ScalarFloat>("temperature_offset", 0.f);
            m_t_cutoff = props.get<ScalarFloat>("temperature_cutoff", 100.f);
            if (!std::isfinite(m_t_scale) || !std::isfinite(m_t_offset) ||
                !(std::isfinite(m_t_cutoff) && m_t_cutoff >= 0.f))
                Throw("emissiveheterogeneous: temperature_scale and temperature_offset must "
                      "be finite and temperature_cutoff finite and >= 0; got %f, %f, %f",
                      m_t_scale, m_t_offset, m_t_cutoff);
            if constexpr (!is_spectral_v<Spectrum>)
                m_blackbody = std::make_unique<Blackbody>();
        }
    }

    // ------------------------------------------------------------------
    //  As heterogeneous
    // ------------------------------------------------------------------

    void traverse(TraversalCallback *cb) override {
        cb->put("scale", m_scale, ParamFlags::NonDifferentiable);
        cb->put("albedo", m_albedo, ParamFlags::Differentiable);
        cb->put("sigma_t", m_sigmat, ParamFlags::Differentiable);
        // emissiveheterogeneous: the emission's parameters
        cb->put("emission_scale", m_emission_scale, ParamFlags::NonDifferentiable);
        if (m_emission)
            cb->put("emission", m_emission, ParamFlags::NonDifferentiable);
        if (m_color)
            cb->put("color", m_color, ParamFlags::NonDifferentiable);
        // emissiveheterogeneous: its emission table's bytes and build time
        // (next-event estimation; 0 until a render built it)
        m_table_bytes = (double) m_sampling.bytes();
        m_table_seconds = m_sampling.build_seconds();
        cb->put("emission_table_bytes", m_table_bytes, ParamFlags::NonDifferentiable);
        cb->put("emission_table_seconds", m_table_seconds, ParamFlags::NonDifferentiable);
        if (m_temperature) {
            cb->put("temperature", m_temperature, ParamFlags::NonDifferentiable);
            cb->put("temperature_scale", m_t_scale, ParamFlags::NonDifferentiable);
            cb->put("temperature_offset", m_t_offset, ParamFlags::NonDifferentiable);
            cb->put("temperature_cutoff", m_t_cutoff, ParamFlags::NonDifferentiable);
        }
        Base::traverse(cb);
    }

    void parameters_changed(const std::vector<std::string> & /*keys*/ = {}) override {
        m_max_density = dr::opaque<Float>(m_scale * m_sigmat->max());
        update_bbox(); // emissiveheterogeneous: the box
        m_sampling_built = false; // emissiveheterogeneous: the emission's table, again
    }

    UnpolarizedSpectrum get_majorant(const MediumInteraction3f & /* mi */,
                                     Mask active) const override {
        MI_MASKED_FUNCTION(ProfilerPhase::MediumEvaluate, active);
        // emissiveheterogeneous: a warning where its emission goes unrendered.
        // Called by Medium::sample_interaction, i.e. by an integrator that
        // tracks the medium itself and so adds no emission
        if (!m_emission_rendered.load(std::memory_order_relaxed) &&
            !m_warned.exchange(true))
            Log(Warn, "emissiveheterogeneous: this integrator renders the medium without "
                      "its emission (%s): only volpathlocal renders emissive media",
                describe(emitter_volume()));
        return m_max_density;
    }

    std::tuple<UnpolarizedSpectrum, UnpolarizedSpectrum, UnpolarizedSpectrum>
    get_scattering_coefficients(const MediumInteraction3f &mi, Mask active) const override {
        MI_MASKED_FUNCTION(ProfilerPhase::MediumEvaluate, active);
        auto sigmat = m_scale * m_sigmat->eval(mi, active);
        if (has_flag(m_phase_function->flags(), PhaseFunctionFlags::Microflake))
            sigmat *= m_phase_function->projected_area(mi, active);
        auto sigmas = sigmat * m_albedo->eval(mi, active);
        auto sigman = m_max_density - sigmat;
        return { sigmas, sigman, sigmat };
    }

    // emissiveheterogeneous: the opaque box (update_bbox); then the emission
    std::tuple<Mask, Float, Float> intersect_aabb(const Ray3f &ray) const override {
        return m_bbox.ray_intersect(ray);
    }

    // ------------------------------------------------------------------
    //  The emission (nanovdb_mitsuba/emissive_medium.h)
    // ------------------------------------------------------------------

    UnpolarizedSpectrum eval_emission(const MediumInteraction3f &mi,
                                      Mask active) const override {
        MI_MASKED_FUNCTION(ProfilerPhase::MediumEvaluate, active);
        UnpolarizedSpectrum le;
        if (m_temperature) {
            // T in kelvin; a blackbody's radiance at T above the cutoff
            Float t = (m_temperature->eval_1(mi, active) - m_t_offset) * m_t_scale;
            Mask hot = active && (t > m_t_cutoff); // (NaN: not hot)
            if constexpr (is_spectral_v<Spectrum>) {
                le = blackbody::planck(mi.wavelengths, t);
            } else {
                auto [rgb, y] = m_blackbody->eval(t, hot);
                if constexpr (is_rgb_v<Spectrum>)
                    le = rgb;
                else
                    le = UnpolarizedSpectrum(y);
            }
            le = dr::select(hot, le, 0.f);
        } else if (m_color) {
            le = m_emission->eval_1(mi, active) * m_color->eval(texture_point(mi), active);
        } else {
            le = m_emission->eval(mi, active);
            if constexpr (is_spectral_v<Spectrum>)
                le *= m_d65->eval(texture_point(mi), active);
        }
        return le * m_emission_scale;
    }

    void set_emission_rendered() const override {
        m_emission_rendered.store(true, std::memory_order_relaxed);
    }

    bool prepare_emission_sampling() const override {
        if (m_sampling_built)
            return m_sampling.valid();
        m_sampling_requested = true;
        // (inside the recording of a frozen function, which cannot replay
        // the build's read-back: no table this time. The next call builds
        // it before recording again, when Dr.Jit traverses the medium)
        if (recording_frozen_function<Float>()) {
            Log(Debug, "emissiveheterogeneous: %s: no emission table inside a frozen "
                       "function's first recording: its emission is rendered by collisions "
                       "there", describe(emitter_volume()));
            return false;
        }
        m_sampling_built = true;
        const Volume *v = emitter_volume();
        const auto *units = dynamic_cast<const GridUnits<Float, Spectrum> *>(v);
        std::string why = units ? m_sampling.build(units, [this](const Point3f &p, Mask active) {
                                      return emitted_weight(p, active);
                                  })
                                : std::string("it is not a nanovdbvolume");
        if (!why.empty()) {
            if (!m_sampling_warned.exchange(true))
                Log(Warn, "emissiveheterogeneous: %s: next-event estimation is off for this "
                          "medium (%s); its emission is still rendered, by collisions only",
                    describe(v), why);
            return false;
        }
        Log(Debug, "emissiveheterogeneous: %s: emission table of %zu bytes in %.3f s",
            describe(v), m_sampling.bytes(), m_sampling.build_seconds());
        return true;
    }

    /// emissiveheterogeneous: the table again where an integrator asked for
    /// it and the values changed since, outside a recording (Dr.Jit's
    /// traversal, below; nanovdb_mitsuba/frozen.h)
    void refresh_emission_sampling() const {
        if (m_sampling_requested && !m_sampling_built && !recording_frozen_function<Float>())
            prepare_emission_sampling();
    }

    double emission_power() const override { return m_sampling.power(); }

    std::pair<Point3f, Float> sample_emission_point(const Float &u, const Point3f &u3,
                                                    Mask active) const override {
        return m_sampling.sample(u, u3, active);
    }

    Float emission_point_pdf(const Point3f &p, Mask active) const override {
        return m_sampling.pdf(p, active);
    }

    std::string to_string() const override {
        std::ostringstream oss;
        // emissiveheterogeneous: its own name, the emission's parameters
        oss << "EmissiveHeterogeneousMedium[" << std::endl
            << "  albedo = " << string::indent(m_albedo) << "," << std::endl
            << "  sigma_t = " << string::indent(m_sigmat) << "," << std::endl
            << "  scale = " << m_scale << "," << std::endl;
        if (m_temperature)
            oss << "  temperature = " << string::indent(m_temperature) << "," << std::endl
                << "  kelvin = (value - " << m_t_offset << ") x " << m_t_scale
                << ", cutoff = " << m_t_cutoff << "," << std::endl;
        else
            oss << "  emission = " << string::indent(m_emission) << "," << std::endl;
        oss << "  emission_scale = " << m_emission_scale << std::endl << "]";
        return oss.str();
    }

    MI_DECLARE_CLASS(EmissiveHeterogeneousMedium) // emissiveheterogeneous: its own name

private:
    // emissiveheterogeneous: helpers of its own
    /// The sigma_t volume's box, opaque: the frames of an animation (each its
    /// own box) then share one kernel, where heterogeneous's box, a literal,
    /// compiles one per frame
    void update_bbox() {
        ScalarBoundingBox3f b = m_sigmat->bbox();
        m_bbox = BoundingBox3f(Point3f(b.min), Point3f(b.max));
        dr::make_opaque(m_bbox.min, m_bbox.max);
    }

    /// What a point emits per unit volume, for the emission's table: the
    /// largest channel of sigma_a Le (spectral variants: at four fixed
    /// wavelengths across the visible range), 0 where that is negative
    /// (a blackbody's sRGB colour below ~1500 K has negative components)
    Float emitted_weight(const Point3f &p, Mask active) const {
        MediumInteraction3f mi = dr::zeros<MediumInteraction3f>(dr::width(p));
        mi.p = p;
        if constexpr (is_spectral_v<Spectrum>)
            mi.wavelengths = Wavelength(450.f, 520.f, 590.f, 660.f);
        auto [sigma_s, sigma_n, sigma_t] = get_scattering_coefficients(mi, active);
        DRJIT_MARK_USED(sigma_n);
        UnpolarizedSpectrum e = (sigma_t - sigma_s) * eval_emission(mi, active);
        return dr::maximum(dr::max(e), 0.f);
    }

    /// Where a texture is looked up (colours vary only with the wavelength)
    static SurfaceInteraction3f texture_point(const MediumInteraction3f &mi) {
        SurfaceInteraction3f si = dr::zeros<SurfaceInteraction3f>();
        si.p = mi.p;
        si.time = mi.time;
        si.wavelengths = mi.wavelengths;
        return si;
    }

    const Volume *emitter_volume() const {
        return m_temperature ? m_temperature.get() : m_emission.get();
    }

    /// A volume named for a message: its file and grid when it has them
    static std::string describe(const Volume *v) {
        if (auto *s = dynamic_cast<const nanovdb_mitsuba::VolumeSource *>(v))
            return s->source_name();
        return "a " + std::string(v->class_name());
    }

    /**
     * Refuses a volume the medium cannot read as `what`: a level set (its
     * values are signed distances, negative inside, not densities), and a
     * channel count other than one (or three, where `colour` allows it).
     */
    static void check_volume(const char *what, const Volume *v, bool colour) {
        auto *s = dynamic_cast<const nanovdb_mitsuba::VolumeSource *>(v);
        if (s && s->grid_class_code() == 1)
            Throw("emissiveheterogeneous: %s: %s is a level set (signed distances, negative "
                  "inside), not a fog volume: it cannot be a %s", what, s->source_name(), what);
        // (0: a constvolume, read with eval_1 like one channel)
        uint32_t n = v->channel_count();
        if (!(n <= 1 || (colour && n == 3)))
            Throw("emissiveheterogeneous: %s: %s has %u channels; the %s volume must have %s",
                  what, describe(v), n, what,
                  colour ? "one (times \"color\") or three (a colour)" : "one");
    }

    ref<Volume> m_sigmat, m_albedo;
    ScalarFloat m_scale;
    Float m_max_density;
    // emissiveheterogeneous: the box, the emission
    BoundingBox3f m_bbox;

    ref<Volume> m_emission, m_temperature;
    ref<Texture> m_color, m_d65;
    ScalarFloat m_emission_scale = 1.f, m_t_scale = 1.f, m_t_offset = 0.f, m_t_cutoff = 100.f;
    std::unique_ptr<Blackbody> m_blackbody; ///< RGB and mono variants, temperature mode

    mutable std::atomic<bool> m_emission_rendered{ false }, m_warned{ false };
    /// The emission as a distribution of points (next-event estimation),
    /// built on the integrator's request, again after a parameter change
    mutable EmissionDistribution<Float, Spectrum> m_sampling;
    mutable bool m_sampling_built = false;
    mutable bool m_sampling_requested = false; ///< an integrator asked for the table
    double m_table_bytes = 0.0, m_table_seconds = 0.0; ///< traverse()'s copies
    mutable std::atomic<bool> m_sampling_warned{ false };

    // emissiveheterogeneous: and its own JIT members (the box by its corners:
    // BoundingBox is no Dr.Jit structure, and Dr.Jit's traversal skipped it,
    // so dr.freeze refused to record a render that reads it), and the
    // emission table, built first where an integrator asked for it and the
    // values changed since (dr.freeze traverses the medium before it
    // records or replays; a replay runs no C++ of ours)
    NVDB_MI_TRAVERSE_CB_REFRESHED(Base, refresh_emission_sampling(), m_sigmat, m_albedo,
                                  m_max_density, m_bbox.min, m_bbox.max, m_emission,
                                  m_temperature, m_color, m_d65, m_sampling)
};

MI_EXPORT_PLUGIN(EmissiveHeterogeneousMedium) // emissiveheterogeneous: its own name
NAMESPACE_END(mitsuba)
