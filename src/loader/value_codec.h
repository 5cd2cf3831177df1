// src/loader/value_codec.h -- how a grid type stores its values, host side.
//
// Internal to the loader. The device reads values with pnanovdb.h's
// per-type readers (root_read_float); the loader needs the same values while
// it validates, sanitizes and builds majorants, and reads them here, with
// the same arithmetic (a quantized value is float(code) * quantum + minimum,
// unfused: the project compiles with -ffp-contract=off), so that the host
// and every backend agree bit for bit.
//
// A value has `channels` floats (3 for Vec3f). Its *bound* is the largest of
// them: what max() and the majorants are built from (a medium's majorant
// bounds every channel).
#pragma once

#include "detail.h"

#include <nanovdb_drjit/layout.h>
#include <nanovdb_loader/validation.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>

namespace nanovdb_loader::detail {

/// IEEE binary16 -> float, exact (every half is a float; NaN made quiet, as
/// pnanovdb.h's half_to_float and x86's F16C do)
inline float half_to_float(uint16_t h) {
    const uint32_t sign = uint32_t(h & 0x8000u) << 16, exponent = (h >> 10) & 0x1fu,
                   mantissa = h & 0x3ffu;
    float magnitude;
    if (exponent == 0) {
        magnitude = float(mantissa) * 5.9604644775390625e-8f; // m * 2^-24
    } else {
        const uint32_t bits = exponent == 31 ? 0x7f800000u | (mantissa << 13) |
                                                   (mantissa ? 0x400000u : 0u)
                                             : ((exponent + 112u) << 23) | (mantissa << 13);
        std::memcpy(&magnitude, &bits, 4);
    }
    uint32_t bits;
    std::memcpy(&bits, &magnitude, 4);
    bits |= sign;
    float out;
    std::memcpy(&out, &bits, 4);
    return out;
}

/// float -> IEEE binary16, rounded to nearest even (overflow to Inf, NaN
/// stays a quiet NaN with the sign)
inline uint16_t float_to_half(float f) {
    uint32_t x;
    std::memcpy(&x, &f, 4);
    const uint16_t sign = uint16_t((x >> 16) & 0x8000u);
    const uint32_t a = x & 0x7fffffffu;
    if (a >= 0x7f800000u) // Inf or NaN
        return uint16_t(sign | 0x7c00u | (a > 0x7f800000u ? 0x200u | ((a >> 13) & 0x3ffu) : 0u));
    if (a >= 0x477ff000u) // >= 65520: rounds to Inf
        return uint16_t(sign | 0x7c00u);
    if (a < 0x38800000u) { // below 2^-14: a subnormal half (or 0)
        // value = a_float; half subnormal unit 2^-24: round(a_float * 2^24)
        float mag;
        std::memcpy(&mag, &a, 4);
        const float scaled = mag * 16777216.f; // exact (power of two)
        return uint16_t(sign | uint16_t(std::nearbyint(scaled)));
    }
    // Normal: rebias, round the 13 dropped mantissa bits to nearest even
    const uint32_t rebased = a - (112u << 23);
    const uint32_t lsb = (rebased >> 13) & 1u;
    return uint16_t(sign | uint16_t((rebased + 0xfffu + lsb) >> 13));
}

/// OnIndex leaves: the value index of voxel n (0..511) of the leaf at
/// `leaf`, as PNanoVDB's pnanovdb_leaf_onindex_get_value_index (0: inactive)
inline uint64_t onindex_leaf_index(const uint8_t *leaf, uint32_t n) {
    const layout::GridTypeConstants &c = layout::GRID_TYPE_CONSTANTS_ONINDEX;
    const uint32_t word = n >> 6;
    const uint64_t mask = load<uint64_t>(leaf + layout::LEAF_OFF_VALUE_MASK + 8 * word),
                   bit = uint64_t(1) << (n & 63);
    if (!(mask & bit))
        return 0;
    uint64_t sum = uint64_t(__builtin_popcountll(mask & (bit - 1)));
    if (word > 0)
        sum += (load<uint64_t>(leaf + c.leaf_off_table + layout::ONINDEX_LEAF_TABLE_OFF_PREFIX_SUM) >>
                (9 * (word - 1))) & 511u;
    return load<uint64_t>(leaf + c.leaf_off_table) + sum;
}

class ValueCodec {
public:
    /// `index`: an index grid's values (required for OnIndex, else unused)
    explicit ValueCodec(uint32_t grid_type, const IndexValues *index = nullptr)
        : m_t(*layout::value_type(grid_type)), m_c(*m_t.constants), m_index(index) {}

    bool indexed() const { return m_t.codec == layout::LeafCodec::OnIndex; }
    /// Index grids: the value of value index i (<= count: validation
    /// checks), `channels` floats into out
    void indexed_value(uint64_t i, float *out) const {
        const uint32_t n = m_index->channels;
        for (uint32_t k = 0; k < n; ++k)
            out[k] = i == 0 ? m_index->background[k] : m_index->values[n * (i - 1) + k];
    }
    /// ... and where it is stored (nullptr: the background)
    float *indexed_slot(uint64_t i) const {
        return i == 0 ? nullptr : m_index->values + m_index->channels * (i - 1);
    }

    const layout::ValueType &type() const { return m_t; }
    const layout::GridTypeConstants &constants() const { return m_c; }
    /// Floats per value (an index grid's: its values', 1 without them)
    uint32_t channels() const { return indexed() ? (m_index ? m_index->channels : 1u) : m_t.channels; }
    bool quantized() const {
        return m_t.codec == layout::LeafCodec::Fixed || m_t.codec == layout::LeafCodec::FpN;
    }
    bool variable_leaf_size() const { return m_t.codec == layout::LeafCodec::FpN; }

    /// Bytes of one tile value (root tile, internal table entry, background)
    uint32_t tile_bytes() const {
        return m_t.codec == layout::LeafCodec::Half ? 2u : indexed() ? 8u : 4u * m_t.channels;
    }

    /// The tile value at p: `channels` floats into out
    void tile(const uint8_t *p, float *out) const {
        if (indexed()) {
            indexed_value(load<uint64_t>(p), out);
            return;
        }
        if (m_t.codec == layout::LeafCodec::Half) {
            out[0] = half_to_float(load<uint16_t>(p));
            return;
        }
        for (uint32_t k = 0; k < m_t.channels; ++k)
            out[k] = load<float>(p + 4 * k);
    }
    /// The tile value's bound (its largest channel)
    float tile_bound(const uint8_t *p) const {
        float v[3] = { 0.f, 0.f, 0.f };
        tile(p, v);
        return bound(v);
    }
    float bound(const float *v) const {
        return channels() == 1 ? v[0] : std::max(v[0], std::max(v[1], v[2]));
    }

    /// log2 of the code width of a quantized leaf (Fp4/8/16: the type's;
    /// FpN: flags >> 5, which validation checks is at most 4)
    uint32_t log2_bits(const uint8_t *leaf) const {
        if (m_t.codec == layout::LeafCodec::FpN)
            return load<uint32_t>(leaf + layout::LEAF_OFF_BBOX_DIF_AND_FLAGS) >> 29;
        return m_t.log2_bits;
    }
    /// Bytes of the leaf at `leaf` (FpN: from its flags)
    uint64_t leaf_size(const uint8_t *leaf) const {
        if (m_t.codec == layout::LeafCodec::FpN)
            return layout::fpn_leaf_size(load<uint32_t>(leaf + layout::LEAF_OFF_BBOX_DIF_AND_FLAGS) >> 24);
        return m_c.leaf_size;
    }

    /// Value n (0..511) of the leaf at `leaf`: `channels` floats into out
    void leaf_value(const uint8_t *leaf, uint32_t n, float *out) const {
        const uint8_t *table = leaf + m_c.leaf_off_table;
        switch (m_t.codec) {
            case layout::LeafCodec::OnIndex: indexed_value(onindex_leaf_index(leaf, n), out); return;
            case layout::LeafCodec::Float32: out[0] = load<float>(table + 4 * n); return;
            case layout::LeafCodec::Half: out[0] = half_to_float(load<uint16_t>(table + 2 * n)); return;
            case layout::LeafCodec::Vec3f:
                for (int k = 0; k < 3; ++k) out[k] = load<float>(table + 12 * n + 4 * k);
                return;
            default: break;
        }
        const uint32_t lb = log2_bits(leaf), bits = 1u << lb, per_word_bits = 5u - lb;
        const uint32_t word = load<uint32_t>(table + 4 * (n >> per_word_bits));
        const uint32_t code = (word >> ((n & ((1u << per_word_bits) - 1u)) << lb)) &
                              ((1u << bits) - 1u); // bits <= 16
        const float minimum = load<float>(table - layout::LEAF_TABLE_NEG_OFF_MINIMUM),
                    quantum = load<float>(table - layout::LEAF_TABLE_NEG_OFF_QUANTUM);
        const float scaled = float(code) * quantum;
        out[0] = scaled + minimum;
    }
    float leaf_bound(const uint8_t *leaf, uint32_t n) const {
        float v[3] = { 0.f, 0.f, 0.f };
        leaf_value(leaf, n, v);
        return bound(v);
    }

    /// All 512 values of a leaf, channel-interleaved (512 * channels floats)
    void leaf(const uint8_t *leaf, float *out) const {
        if (m_t.codec == layout::LeafCodec::Float32 || m_t.codec == layout::LeafCodec::Vec3f) {
            std::memcpy(out, leaf + m_c.leaf_off_table, 512 * 4 * m_t.channels);
            return;
        }
        const uint32_t stride = channels();
        for (uint32_t n = 0; n < 512; ++n)
            leaf_value(leaf, n, out + stride * n);
    }

    /// Byte offset, within the leaf, of the bytes that hold value n (its
    /// table word for quantized leaves): what error messages point at
    uint64_t leaf_value_offset(uint32_t n) const {
        if (quantized())
            return m_c.leaf_off_table;
        return m_c.leaf_off_table + uint64_t(n) * m_c.value_stride_bits / 8;
    }

private:
    const layout::ValueType &m_t;
    const layout::GridTypeConstants &m_c;
    const IndexValues *m_index;
};

} // namespace nanovdb_loader::detail
