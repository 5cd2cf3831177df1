/*
    The emission distribution's table (src/loader/emission_table.cpp) and
    its sampling (nanovdb_drjit/emission_sampling.h), against the weights
    it was built from: every block's and tile's probability sums to 1 and
    follows its rounded-up 4-bit weight; sampling picks units and blocks
    with those probabilities (a chi-square test over every block and tile)
    and returns the very probability that emission_probability() computes
    again for the same block; bad weights are refused. Scalar and LLVM
    (the same picks for the same random numbers).
*/

#include <nanovdb_drjit/emission_sampling.h>
#include <nanovdb_loader/emission_table.h>

#include "backends.h"

#include <doctest/doctest.h>

#include <cmath>
#include <limits>
#include <map>
#include <random>
#include <stdexcept>

namespace dr = drjit;
namespace nd = nanovdb_drjit;
namespace nl = nanovdb_loader;

namespace {

/// Leaves of sparse random weights (some leaves and blocks empty, a range
/// of 1e6 between voxels), and tiles (one of them 0)
struct Weights {
    std::vector<float> leaves, tiles;
};

Weights random_weights(uint32_t leaves, uint32_t seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> u(0.f, 1.f);
    Weights w;
    w.leaves.assign(size_t(leaves) * 512, 0.f);
    for (uint32_t l = 0; l < leaves; ++l) {
        if (l % 7 == 3)
            continue; // an empty leaf
        const float fill = u(rng);
        for (uint32_t n = 0; n < 512; ++n)
            if (u(rng) < fill)
                w.leaves[size_t(l) * 512 + n] = std::pow(10.f, -6.f * u(rng)) * (1 + l % 5);
    }
    w.tiles = { 30.f, 0.f, 2.5f, 900.f };
    return w;
}

uint32_t q_of(const nl::EmissionTable &t, uint32_t l, uint32_t b) {
    const uint32_t units = t.leaf_count + t.tile_count;
    return (t.words[nd::emission_leaf_word(units, l) + b / 8] >> (4 * (b % 8))) & 0xfu;
}

float prob(const nl::EmissionTable &t, uint32_t unit, uint32_t block) {
    return nd::emission_probability<uint32_t>(t.words.data(), t.leaf_count + t.tile_count,
                                              t.leaf_count, unit, block, true);
}

} // namespace

TEST_CASE("emission table: probabilities, quantization, refusals") {
    const Weights w = random_weights(40, 1);
    const nl::EmissionTable t = nl::build_emission_table(w.leaves, w.tiles);
    REQUIRE(t.leaf_count == 40);
    REQUIRE(t.tile_count == 4);
    double sum = 0.0;
    for (uint32_t l = 0; l < t.leaf_count; ++l) {
        double block[64] = {}, top = 0.0;
        for (uint32_t n = 0; n < 512; ++n)
            block[nd::emission_block(n >> 6, (n >> 3) & 7, n & 7)] += w.leaves[l * 512 + n];
        for (double b : block)
            top = std::max(top, b);
        for (uint32_t b = 0; b < 64; ++b) {
            const uint32_t q = q_of(t, l, b);
            // no emitting block left out; q is its weight's fraction, rounded up
            CHECK((q > 0) == (block[b] > 0.0));
            if (block[b] > 0.0) {
                CHECK(double(q) >= 15.0 * block[b] / top - 1e-6);
                CHECK(double(q) < 15.0 * block[b] / top + 1.0);
            }
            sum += prob(t, l, b);
        }
    }
    for (uint32_t k = 0; k < t.tile_count; ++k) {
        CHECK(prob(t, t.leaf_count + k, 0) == doctest::Approx(w.tiles[k] / t.total).epsilon(1e-5));
        sum += prob(t, t.leaf_count + k, 0);
    }
    CHECK(sum == doctest::Approx(1.0).epsilon(1e-5));

    // Refused: a negative, NaN or infinite weight, zero power, a ragged leaf
    auto refused = [](std::vector<float> leaves, std::vector<float> tiles) {
        CHECK_THROWS_AS(nl::build_emission_table(leaves, tiles), std::invalid_argument);
    };
    std::vector<float> bad = w.leaves;
    bad[77] = -1.f;
    refused(bad, w.tiles);
    bad[77] = std::numeric_limits<float>::quiet_NaN();
    refused(bad, w.tiles);
    refused(w.leaves, { std::numeric_limits<float>::infinity() });
    refused(std::vector<float>(1024, 0.f), { 0.f });
    refused(std::vector<float>(100, 1.f), {});
}

TEST_CASE("emission table: sampling follows the probabilities, and returns them") {
    const Weights w = random_weights(24, 2);
    const nl::EmissionTable t = nl::build_emission_table(w.leaves, w.tiles);
    const uint32_t units = t.leaf_count + t.tile_count;
    const size_t n = 2000000;
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(0.f, 1.f);
    std::map<std::pair<uint32_t, uint32_t>, size_t> count;
    size_t returned_differs = 0, zero_picked = 0, rest_outside = 0;
    double rest_sum = 0.0;
    for (size_t i = 0; i < n; ++i) {
        const auto p = nd::sample_emission<uint32_t>(t.words.data(), units, t.leaf_count, u(rng), true);
        ++count[{ p.unit, p.block }];
        returned_differs += p.prob != prob(t, p.unit, p.block);
        zero_picked += !(p.prob > 0.f);
        rest_sum += p.rest;
        rest_outside += !(p.rest >= 0.f && p.rest < 1.f);
    }
    CHECK(returned_differs == 0);
    CHECK(zero_picked == 0);
    CHECK(rest_outside == 0);
    CHECK(rest_sum / n == doctest::Approx(0.5).epsilon(0.002));
    // Chi-square over every block and tile of probability > 0 (bins of
    // fewer than 20 expected merged into one)
    double chi2 = 0.0, small_expected = 0.0, small_seen = 0.0;
    int bins = 0;
    auto add = [&](double expected, double seen) {
        if (expected < 20.0) {
            small_expected += expected;
            small_seen += seen;
            return;
        }
        chi2 += (seen - expected) * (seen - expected) / expected;
        ++bins;
    };
    for (uint32_t unit = 0; unit < units; ++unit)
        for (uint32_t b = 0; b < (unit < t.leaf_count ? 64u : 1u); ++b) {
            const double p = prob(t, unit, b);
            const auto it = count.find({ unit, b });
            const double seen = it == count.end() ? 0.0 : double(it->second);
            if (p == 0.0)
                CHECK(seen == 0.0);
            else
                add(p * n, seen);
        }
    if (small_expected > 0.0) {
        chi2 += (small_seen - small_expected) * (small_seen - small_expected) / small_expected;
        ++bins;
    }
    // Wilson-Hilferty: the chi-square's 1 - 1e-6 quantile for bins - 1
    // degrees of freedom (z = 4.75)
    const double k = bins - 1, z = 4.75;
    const double limit = k * std::pow(1.0 - 2.0 / (9.0 * k) + z * std::sqrt(2.0 / (9.0 * k)), 3.0);
    INFO("chi2 " << chi2 << " over " << bins << " bins, limit " << limit);
    CHECK(bins > 500);
    CHECK(chi2 < limit);
}

TEST_CASE("emission table: LLVM picks what the scalar path picks") {
    using UInt32 = dr::LLVMArray<uint32_t>;
    using Float = dr::LLVMArray<float>;
    nvdb_test::init_backend<UInt32>();
    const Weights w = random_weights(17, 4);
    const nl::EmissionTable t = nl::build_emission_table(w.leaves, w.tiles);
    const uint32_t units = t.leaf_count + t.tile_count;
    std::vector<float> xs(4096);
    std::mt19937 rng(5);
    std::uniform_real_distribution<float> u(0.f, 1.f);
    for (float &x : xs)
        x = u(rng);
    const UInt32 table = dr::load<UInt32>(t.words.data(), t.words.size());
    const auto p = nd::sample_emission<UInt32>(table, units, t.leaf_count,
                                               dr::load<Float>(xs.data(), xs.size()), true);
    const auto again = nd::emission_probability<UInt32>(table, units, t.leaf_count, p.unit,
                                                        p.block, true);
    dr::eval(p.unit, p.block, p.prob, p.rest, again);
    size_t differs = 0;
    for (size_t i = 0; i < xs.size(); ++i) {
        const auto s = nd::sample_emission<uint32_t>(t.words.data(), units, t.leaf_count, xs[i], true);
        differs += s.unit != dr::slice(p.unit, i) || s.block != dr::slice(p.block, i) ||
                   s.prob != dr::slice(p.prob, i) || s.prob != dr::slice(again, i) ||
                   std::abs(s.rest - dr::slice(p.rest, i)) > 1e-6f;
    }
    CHECK(differs == 0);
}
