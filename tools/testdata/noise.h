// Deterministic value noise of the test volumes: functions of the lattice
// point and a seed only (seeded.h), so the grids are the same on every
// platform and under any thread schedule. Two families, kept apart because
// the grids built from them must not change: the test suite's (smoothstep,
// 4 octaves: test_grids.h) and vdb2nvdb generate's (quintic, 5 octaves:
// generate_cases.h).
#pragma once

#include <cmath>
#include <cstdint>

#include "seeded.h"

namespace nvdb_testdata {

// The test suite's noise (noisy_cloud)

/// Lattice hash in [0, 1): splitmix64 chained over x, y, z
inline double lattice01(int64_t x, int64_t y, int64_t z, uint64_t seed) {
    uint64_t h = splitmix64(seed ^ uint64_t(x));
    h = splitmix64(h ^ uint64_t(y));
    h = splitmix64(h ^ uint64_t(z));
    return unit_interval(h);
}

/// Value noise in [0, 1): trilinear interpolation of lattice hashes with
/// smoothstep weights.
inline double smooth_noise(double x, double y, double z, uint64_t seed) {
    const double fx = std::floor(x), fy = std::floor(y), fz = std::floor(z);
    const int64_t ix = int64_t(fx), iy = int64_t(fy), iz = int64_t(fz);
    auto smooth = [](double t) { return t * t * (3.0 - 2.0 * t); };
    const double u = smooth(x - fx), v = smooth(y - fy), w = smooth(z - fz);
    double c[2][2][2];
    for (int dx = 0; dx < 2; ++dx)
        for (int dy = 0; dy < 2; ++dy)
            for (int dz = 0; dz < 2; ++dz)
                c[dx][dy][dz] = lattice01(ix + dx, iy + dy, iz + dz, seed);
    auto lerp = [](double a, double b, double t) { return a + (b - a) * t; };
    const double x00 = lerp(c[0][0][0], c[1][0][0], u), x10 = lerp(c[0][1][0], c[1][1][0], u),
                 x01 = lerp(c[0][0][1], c[1][0][1], u), x11 = lerp(c[0][1][1], c[1][1][1], u);
    return lerp(lerp(x00, x10, v), lerp(x01, x11, v), w);
}

/// Fractal sum of 4 octaves of smooth_noise, normalised to [0, 1).
inline double smooth_fbm(double x, double y, double z, uint64_t seed) {
    double sum = 0.0, amplitude = 1.0, norm = 0.0, f = 1.0;
    for (int octave = 0; octave < 4; ++octave) {
        sum += amplitude * smooth_noise(x * f, y * f, z * f, seed + uint64_t(octave));
        norm += amplitude;
        amplitude *= 0.5;
        f *= 2.0;
    }
    return sum / norm;
}

// vdb2nvdb generate's noise (cloud, cloudfield, random_<N>, multi)

/// Hash of a lattice point in [0, 1): mix64 over the seed and x, y, z, each
/// axis with its own odd multiplier
inline double hash01(int64_t x, int64_t y, int64_t z, uint64_t seed) {
    uint64_t h = splitmix64(seed);
    h = mix64(h ^ (uint64_t(x) * 0xD1B54A32D192ED03ull));
    h = mix64(h ^ (uint64_t(y) * 0xABC98388FB8FAC03ull));
    h = mix64(h ^ (uint64_t(z) * 0x8CB92BA72F3D8DD7ull));
    return unit_interval(h);
}

/// Value noise in [0, 1): lattice hashes blended with quintic fades.
inline double quintic_noise(double x, double y, double z, uint64_t seed) {
    const double fx = std::floor(x), fy = std::floor(y), fz = std::floor(z);
    const int64_t ix = int64_t(fx), iy = int64_t(fy), iz = int64_t(fz);
    auto fade = [](double t) { return t * t * t * (t * (t * 6.0 - 15.0) + 10.0); };
    const double u = fade(x - fx), v = fade(y - fy), w = fade(z - fz);
    double acc = 0.0;
    for (int c = 0; c < 8; ++c) {
        const int dx = c & 1, dy = (c >> 1) & 1, dz = (c >> 2) & 1;
        const double wgt = (dx ? u : 1 - u) * (dy ? v : 1 - v) * (dz ? w : 1 - w);
        acc += wgt * hash01(ix + dx, iy + dy, iz + dz, seed);
    }
    return acc;
}

/// 5 octaves of quintic_noise, each shifted, normalised to [0, 1).
inline double quintic_fbm(double x, double y, double z, uint64_t seed) {
    double sum = 0.0, amp = 1.0, norm = 0.0, f = 1.0;
    for (int o = 0; o < 5; ++o) {
        sum += amp * quintic_noise(x * f + 17.3 * o, y * f - 5.1 * o, z * f + 9.7 * o, seed + o);
        norm += amp;
        amp *= 0.5;
        f *= 2.03;
    }
    return sum / norm;
}

} // namespace nvdb_testdata
