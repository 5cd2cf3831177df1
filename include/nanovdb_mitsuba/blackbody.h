/*
    nanovdb_mitsuba/blackbody.h -- the radiance of a blackbody at a
    temperature that varies per lane, in Mitsuba's units, for every variant

    Mitsuba's `blackbody` spectrum (src/spectra/blackbody.cpp) has one
    temperature per object and throws in RGB and monochrome variants. An
    emissive medium needs a temperature per lookup, so:

      planck()          Planck's law at wavelengths in nm, in W m^-2 sr^-1 nm^-1:
                        what `blackbody` returns (same constants, same 1e-9
                        from per metre to per nm), 0 outside [360, 830] nm
      BlackbodyColor    for RGB and mono variants: the linear sRGB colour
                        (mono: the luminance Y) a spectral variant's film
                        makes of that spectrum, i.e. the integral over
                        [360, 830] nm of planck() x the CIE 1931 curves,
                        times MI_CIE_Y_NORMALIZATION, then XYZ -> sRGB
                        (mitsuba/core/spectrum.h's spectrum_to_srgb in the
                        limit of many wavelengths). Tabulated once per
                        medium, at kTableSize temperatures spaced evenly in
                        log T over [kTmin, kTmax]; a lookup interpolates
                        log Y and the colour over Y linearly (relative error
                        below 3e-4 of Y, tests/test_emission.py). Below kTmin the
                        visible radiance is below 1e-20 of its value at
                        1000 K: 0. Above kTmax it grows linearly in T
                        (Rayleigh-Jeans; 20 % off at 1e6 K).

    Colours of a blackbody below about 1500 K have a negative blue component
    in linear sRGB (outside its gamut; 1000 K: -0.09 of Y). The table clips
    negative components to 0: a negative radiance in an RGB variant's path
    makes negative samples (Mitsuba warns of each) and cancellations. Spectral
    variants keep the spectrum, whose film colour is then negative there.
*/

#pragma once

#include <mitsuba/core/spectrum.h>

#include <algorithm>
#include <cmath>
#include <vector>

NAMESPACE_BEGIN(mitsuba)
namespace blackbody {

// The constants of Mitsuba's blackbody.cpp (CODATA 2014)
constexpr double kC = 2.99792458e+8;   ///< speed of light, m/s
constexpr double kH = 6.62607004e-34;  ///< Planck constant, J s
constexpr double kK = 1.38064852e-23;  ///< Boltzmann constant, J/K
constexpr double kC0 = 2 * kH * kC * kC; ///< first radiation constant (radiance), W m^2 / sr
constexpr double kC1 = kH * kC / kK;     ///< second radiation constant, m K

/**
 * Planck's law: spectral radiance at `lambda_nm` (nanometres) of a
 * blackbody at temperature `t` (kelvin), in W m^-2 sr^-1 nm^-1; 0 where
 * t <= 0 and outside Mitsuba's [MI_CIE_MIN, MI_CIE_MAX]. Written with
 * exp(-x) rather than 1 / (exp(x) - 1), so that cold lanes give 0, never
 * inf / inf.
 */
template <typename Value, typename T>
Value planck(const Value &lambda_nm, const T &t) {
    using Scalar = dr::scalar_t<Value>;
    Value lambda = lambda_nm * Scalar(1e-9), lambda5 = dr::square(dr::square(lambda)) * lambda;
    Value x = Scalar(kC1) / (lambda * t), e = dr::exp(-x);
    Value p = Scalar(1e-9 * kC0) * e / (lambda5 * (1.f - e));
    auto valid = (t > 0.f) && (lambda_nm >= (Scalar) MI_CIE_MIN) &&
                 (lambda_nm <= (Scalar) MI_CIE_MAX) && (x > 0.f);
    return dr::select(valid, p, 0.f);
}

/// The table's range and size (see the file's comment)
constexpr double kTmin = 400.0, kTmax = 1e5;
constexpr uint32_t kTableSize = 2048;

/**
 * The CIE XYZ of a blackbody at `t` kelvin, as a spectral film sees it: the
 * integral of planck() x the CIE 1931 curves over [360, 830] nm (0.25 nm
 * trapezoids, in double) times MI_CIE_Y_NORMALIZATION. Host code.
 */
inline Color<double, 3> xyz(double t) {
    constexpr int steps = 4 * int(MI_CIE_MAX - MI_CIE_MIN); // 0.25 nm
    Color<double, 3> sum(0.0);
    for (int i = 0; i <= steps; ++i) {
        float lambda = MI_CIE_MIN + 0.25f * float(i);
        Color<float, 3> cmf = cie1931_xyz<float>(lambda);
        double x = kC1 / (double(lambda) * 1e-9 * t),
               p = 1e-9 * kC0 * std::exp(-x) /
                   (std::pow(double(lambda) * 1e-9, 5) * -std::expm1(-x));
        double w = (i == 0 || i == steps) ? 0.125 : 0.25;
        for (int c = 0; c < 3; ++c)
            sum[c] += w * p * double(cmf[c]);
    }
    return sum * MI_CIE_Y_NORMALIZATION;
}

/**
 * A blackbody's colour (linear sRGB, negative components clipped to 0; Y for
 * mono) per lane, from a table on the variant's backend: row i holds
 * (log Y, R/Y, G/Y, B/Y) at
 * T_i = kTmin (kTmax / kTmin)^(i / (kTableSize - 1)).
 */
template <typename Float> class BlackbodyColor {
public:
    using ScalarFloat = dr::scalar_t<Float>;
    using UInt32 = dr::uint32_array_t<Float>;
    using Mask = dr::mask_t<Float>;
    using FloatStorage = DynamicBuffer<Float>;
    using Color3f = Color<Float, 3>;

    BlackbodyColor() {
        std::vector<ScalarFloat> rows(4 * kTableSize);
        for (uint32_t i = 0; i < kTableSize; ++i) {
            double t = kTmin * std::pow(kTmax / kTmin, double(i) / (kTableSize - 1));
            Color<double, 3> c = xyz(t);
            double r = 3.240479 * c[0] - 1.537150 * c[1] - 0.498535 * c[2],
                   g = -0.969256 * c[0] + 1.875991 * c[1] + 0.041556 * c[2],
                   b = 0.055648 * c[0] - 0.204043 * c[1] + 1.057311 * c[2];
            rows[4 * i + 0] = ScalarFloat(std::log(c[1]));
            rows[4 * i + 1] = ScalarFloat(std::max(r, 0.0) / c[1]);
            rows[4 * i + 2] = ScalarFloat(std::max(g, 0.0) / c[1]);
            rows[4 * i + 3] = ScalarFloat(std::max(b, 0.0) / c[1]);
        }
        m_rows = dr::load<FloatStorage>(rows.data(), rows.size());
    }

    /// (linear sRGB, Y) of a blackbody at `t` kelvin (0 at or below kTmin)
    std::pair<Color3f, Float> eval(const Float &t, Mask active) const {
        const double span = std::log(kTmax / kTmin);
        Float u = (dr::log(dr::maximum(t, ScalarFloat(kTmin))) - ScalarFloat(std::log(kTmin))) *
                  ScalarFloat((kTableSize - 1) / span);
        active &= t > ScalarFloat(kTmin);
        UInt32 i0 = dr::minimum(UInt32(dr::maximum(u, 0.f)), kTableSize - 2);
        Float w = dr::minimum(u - Float(i0), 1.f);
        auto row = [&](const UInt32 &i) {
            return dr::gather<dr::Array<Float, 4>>(m_rows, i, active);
        };
        dr::Array<Float, 4> a = row(i0), b = row(i0 + 1u), v = dr::lerp(a, b, w);
        // (Rayleigh-Jeans beyond the table: radiance proportional to T)
        Float y = dr::exp(v[0]) * dr::maximum(t * ScalarFloat(1.0 / kTmax), 1.f);
        y = dr::select(active, y, 0.f);
        return { Color3f(v[1], v[2], v[3]) * y, y };
    }

    FloatStorage m_rows;
};

} // namespace blackbody
NAMESPACE_END(mitsuba)
