// The emission distribution's table (nanovdb_drjit/emission_table.h).

#include <nanovdb_drjit/emission_table.h>
#include <nanovdb_loader/emission_table.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <string>

namespace nanovdb_loader {

namespace nd = nanovdb_drjit;

namespace {

uint32_t float_bits(float v) {
    uint32_t b;
    std::memcpy(&b, &v, 4);
    return b;
}

float bits_float(uint32_t b) {
    float v;
    std::memcpy(&v, &b, 4);
    return v;
}

void check(float w, const char *what, size_t index) {
    if (!(std::isfinite(w) && w >= 0.f))
        throw std::invalid_argument(std::string("emission weight of ") + what + " " +
                                    std::to_string(index) + " is " + std::to_string(w) +
                                    ": weights must be finite and >= 0");
}

} // namespace

EmissionTable build_emission_table(const std::vector<float> &leaf_weights,
                                   const std::vector<float> &tile_weights) {
    if (leaf_weights.size() % 512 != 0)
        throw std::invalid_argument("emission weights: " + std::to_string(leaf_weights.size()) +
                                    " leaf voxel weights, not a multiple of 512");
    EmissionTable t;
    t.leaf_count = uint32_t(leaf_weights.size() / 512);
    t.tile_count = uint32_t(tile_weights.size());
    const uint32_t units = t.leaf_count + t.tile_count;

    // Per unit: its weight (double sums), per leaf its blocks'
    std::vector<double> unit(units, 0.0), block(size_t(t.leaf_count) * nd::EMISSION_BLOCKS, 0.0);
    for (uint32_t l = 0; l < t.leaf_count; ++l)
        for (uint32_t n = 0; n < 512; ++n) {
            const float w = leaf_weights[size_t(l) * 512 + n];
            check(w, "voxel", size_t(l) * 512 + n);
            block[size_t(l) * nd::EMISSION_BLOCKS + nd::emission_block(n >> 6, (n >> 3) & 7, n & 7)] += w;
        }
    for (uint32_t l = 0; l < t.leaf_count; ++l)
        for (uint32_t b = 0; b < nd::EMISSION_BLOCKS; ++b)
            unit[l] += block[size_t(l) * nd::EMISSION_BLOCKS + b];
    for (uint32_t k = 0; k < t.tile_count; ++k) {
        check(tile_weights[k], "tile", k);
        unit[t.leaf_count + k] = tile_weights[k];
    }
    for (double u : unit)
        t.total += u;
    if (!(t.total > 0.0))
        throw std::invalid_argument("the emission has zero power (every weight is 0)");

    t.words.assign(units + 1 + size_t(nd::EMISSION_LEAF_WORDS) * t.leaf_count + t.tile_count, 0u);
    // The CDF, in double, stored as floats; the last entry exactly 1
    std::vector<float> cdf(units + 1);
    double acc = 0.0;
    for (uint32_t u = 0; u < units; ++u) {
        cdf[u] = float(acc / t.total);
        acc += unit[u];
    }
    cdf[units] = 1.f;
    for (uint32_t u = 0; u <= units; ++u)
        t.words[u] = float_bits(cdf[u]);

    for (uint32_t l = 0; l < t.leaf_count; ++l) {
        const double *bw = &block[size_t(l) * nd::EMISSION_BLOCKS];
        const double top = *std::max_element(bw, bw + nd::EMISSION_BLOCKS);
        uint32_t *w = &t.words[nd::emission_leaf_word(units, l)];
        uint32_t sum = 0;
        for (uint32_t b = 0; b < nd::EMISSION_BLOCKS; ++b) {
            uint32_t q = 0;
            if (bw[b] > 0.0) // rounded up: 1..15, no emitting block gets 0
                q = std::clamp<uint32_t>(uint32_t(std::ceil(nd::EMISSION_LEVELS * (bw[b] / top))),
                                         1u, nd::EMISSION_LEVELS);
            w[b / 8] |= q << (4 * (b % 8));
            sum += q;
        }
        // (the same float arithmetic as the device's: see emission_sampling.h)
        const float p = bits_float(t.words[l + 1]) - bits_float(t.words[l]);
        w[nd::EMISSION_BLOCK_WORDS] = float_bits(sum > 0 ? p / float(sum) : 0.f);
    }
    for (uint32_t k = 0; k < t.tile_count; ++k) {
        const uint32_t u = t.leaf_count + k;
        t.words[nd::emission_tile_word(units, t.leaf_count, k)] =
            float_bits(bits_float(t.words[u + 1]) - bits_float(t.words[u]));
    }
    return t;
}

} // namespace nanovdb_loader
