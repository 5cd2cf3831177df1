// src/loader/values.cpp -- the value policy (see values.h).

#include <nanovdb_loader/values.h>

#include "detail.h"
#include "value_codec.h"
#include "value_stats.h"

#include <cmath>
#include <limits>

namespace nanovdb_loader {

/// The one writer of a ValidatedGrid's values (a friend of the class)
struct ValueRewriter {
    /// The buffer, for writing; Error if it was validated as read-only
    static uint8_t *data(ValidatedGrid &grid) {
        if (!grid.m_writable)
            detail::fail(grid.m_path, "internal error: sanitize_values() on a grid "
                                      "validated from a read-only buffer");
        return grid.m_data;
    }
    static void set_values(ValidatedGrid &grid, const ValueStats &stats,
                           std::vector<float> leaf_min, std::vector<float> leaf_max) {
        grid.m_values = stats;
        grid.m_leaf_min = std::move(leaf_min);
        grid.m_leaf_max = std::move(leaf_max);
    }
};

namespace {

using namespace detail;

const layout::GridTypeConstants &constants(const ValidatedGrid &grid) {
    return *layout::grid_type_constants(grid.summary().grid_type);
}

/// Levels 0 (leaf), 1 (lower), 2 (upper): node size, the entry table, and
/// the log2 of the entries per axis and of the voxels an entry spans
struct Level {
    uint64_t node_size, table_off, table_stride, mask_off, table_count;
    uint32_t log2dim, log2entry;
};

Level level_of(const layout::GridTypeConstants &c, int level) {
    switch (level) {
        case 0: return { c.leaf_size, c.leaf_off_table, c.value_stride_bits / 8, 0,
                         layout::LEAF_TABLE_COUNT, layout::LEAF_LOG2_DIM, 0 };
        case 1: return { c.lower_size, c.lower_off_table, c.table_stride,
                         layout::LOWER_OFF_CHILD_MASK, layout::LOWER_TABLE_COUNT,
                         layout::LOWER_LOG2_DIM, layout::LOWER_ENTRY_LOG2 };
        default: return { c.upper_size, c.upper_off_table, c.table_stride,
                          layout::UPPER_OFF_CHILD_MASK, layout::UPPER_TABLE_COUNT,
                          layout::UPPER_LOG2_DIM, layout::UPPER_ENTRY_LOG2 };
    }
}

bool child_bit(const uint8_t *node, const Level &l, uint64_t e) {
    return (load<uint32_t>(node + l.mask_off + 4 * (e >> 5)) >> (e & 31)) & 1u;
}

/// Table entry e of a node whose first voxel is `o`: the entry's first voxel
void entry_origin(uint64_t e, const Level &l, const int32_t *o, int32_t *out) {
    const uint64_t mask = (uint64_t(1) << l.log2dim) - 1;
    const uint64_t i = e >> (2 * l.log2dim), j = (e >> l.log2dim) & mask, k = e & mask;
    out[0] = int32_t(uint32_t(o[0]) + (uint32_t(i) << l.log2entry));
    out[1] = int32_t(uint32_t(o[1]) + (uint32_t(j) << l.log2entry));
    out[2] = int32_t(uint32_t(o[2]) + (uint32_t(k) << l.log2entry));
}

/// The first voxel of every node, from the root keys down (first path wins);
/// nodes that no root tile reaches keep `set == false`
struct NodeOrigins {
    struct Origin { int32_t ijk[3]; bool set; };
    std::vector<Origin> origin[3]; // leaf, lower, upper

    explicit NodeOrigins(const ValidatedGrid &grid) {
        const GridSummary &s = grid.summary();
        const layout::GridTypeConstants &c = constants(grid);
        const uint8_t *buf = grid.data();
        for (int l = 0; l < 3; ++l)
            origin[l].assign(s.node_count[l], Origin{ { 0, 0, 0 }, false });
        auto child_index = [&](int level, uint64_t parent, int64_t delta) {
            const uint64_t target = uint64_t(int64_t(parent) + delta); // validated
            if (level == 0)
                return size_t(grid.leaf_containing(target));
            return size_t((target - s.node_begin[level]) / level_of(c, level).node_size);
        };
        const uint64_t root = uint64_t(s.root_word) * 4;
        for (uint64_t i = 0; i < s.root_tile_count; ++i) {
            const uint8_t *tile = buf + root + c.root_size + i * c.root_tile_size;
            const int64_t child = load<int64_t>(tile + layout::ROOT_TILE_OFF_CHILD);
            if (child == 0) continue;
            Origin &o = origin[2][child_index(2, root, child)];
            if (o.set) continue;
            layout::key_to_origin(load<uint64_t>(tile + layout::ROOT_TILE_OFF_KEY), o.ijk);
            o.set = true;
        }
        for (int level : { 2, 1 }) {
            const Level l = level_of(c, level);
            for (uint64_t n = 0; n < s.node_count[level]; ++n) {
                const Origin &o = origin[level][size_t(n)];
                if (!o.set) continue; // unreachable: its children keep no origin from it
                const uint64_t node = s.node_begin[level] + n * l.node_size;
                for (uint64_t e = 0; e < l.table_count; ++e) {
                    if (!child_bit(buf + node, l, e))
                        continue;
                    Origin &child = origin[level - 1][child_index(
                        level - 1, node, load<int64_t>(buf + node + l.table_off + e * l.table_stride))];
                    if (child.set) continue;
                    entry_origin(e, l, o.ijk, child.ijk);
                    child.set = true;
                }
            }
        }
    }
};

/// Visits every value outside the leaves that validation counts, in the same
/// order, as f(pointer to the value (maybe unaligned), its byte offset)
template <typename F> void for_each_tile_value(ValidatedGrid &grid, F &&f) {
    const GridSummary &s = grid.summary();
    const layout::GridTypeConstants &c = constants(grid);
    uint8_t *buf = ValueRewriter::data(grid);
    const uint64_t root = uint64_t(s.root_word) * 4;
    f(buf + root + c.root_off_background, root + c.root_off_background);
    for (uint64_t i = 0; i < s.root_tile_count; ++i) {
        const uint64_t tile = root + c.root_size + i * c.root_tile_size;
        if (load<int64_t>(buf + tile + layout::ROOT_TILE_OFF_CHILD) == 0)
            f(buf + tile + c.root_tile_off_value, tile + c.root_tile_off_value);
    }
    for (int level : { 2, 1 }) {
        const Level l = level_of(c, level);
        for (uint64_t n = 0; n < s.node_count[level]; ++n) {
            const uint64_t node = s.node_begin[level] + n * l.node_size;
            for (uint64_t e = 0; e < l.table_count; ++e) {
                if (child_bit(buf + node, l, e))
                    continue;
                const uint64_t at = node + l.table_off + e * l.table_stride;
                f(buf + at, at);
            }
        }
    }
}

/// loc.level and loc.ijk of entry e of node n (at byte `node`) of `level`
void locate_entry(const ValidatedGrid &grid, int level, size_t n, uint64_t node, uint64_t e,
                  ValueLocation &loc) {
    const NodeOrigins origins(grid);
    const NodeOrigins::Origin &o = origins.origin[level][n];
    int32_t base[3];
    if (o.set) {
        for (int k = 0; k < 3; ++k) base[k] = o.ijk[k];
    } else { // the node's own bbox minimum, rounded down to the node size
        const uint32_t m = level == 0 ? 7u : level == 1 ? 127u : 4095u;
        for (int k = 0; k < 3; ++k)
            base[k] = int32_t(load<uint32_t>(grid.data() + node + 4 * k) & ~m);
        loc.reachable = false;
    }
    loc.level = uint32_t(level);
    entry_origin(e, level_of(constants(grid), level), base, loc.ijk);
}

} // namespace

ValueLocation locate_value(const ValidatedGrid &grid, uint64_t key) {
    const GridSummary &s = grid.summary();
    const layout::GridTypeConstants &c = constants(grid);
    const uint8_t *buf = grid.data();
    const uint64_t root = uint64_t(s.root_word) * 4,
                   tiles = root + c.root_size;
    ValueLocation loc;
    if (key & ValueStats::LEAF_VALUE) { // leaf index << 9 | n
        const uint64_t leaf = (key & ~ValueStats::LEAF_VALUE) >> 9, node = grid.leaf_byte(leaf);
        const uint32_t n = uint32_t(key & 511u);
        loc.byte = node + ValueCodec(s.grid_type).leaf_value_offset(n);
        locate_entry(grid, 0, size_t(leaf), node, n, loc);
        return loc;
    }
    const uint64_t byte = key;
    loc.byte = byte;
    if (byte >= tiles && byte < tiles + uint64_t(s.root_tile_count) * c.root_tile_size) {
        const uint64_t tile = tiles + (byte - tiles) / c.root_tile_size * c.root_tile_size;
        loc.level = 3;
        layout::key_to_origin(load<uint64_t>(buf + tile + layout::ROOT_TILE_OFF_KEY), loc.ijk);
        return loc;
    }
    for (int level : { 2, 1 }) {
        const Level l = level_of(c, level);
        const uint64_t begin = s.node_begin[level], end = s.node_end[level];
        if (s.node_count[level] == 0 || byte < begin || byte >= end)
            continue;
        const uint64_t n = (byte - begin) / l.node_size,
                       node = begin + n * l.node_size,
                       e = (byte - node - l.table_off) / l.table_stride;
        locate_entry(grid, level, size_t(n), node, e, loc);
        return loc;
    }
    return loc; // the background
}

std::string describe_location(const ValueLocation &l) {
    if (l.level >= 4)
        return "background";
    static const char *what[] = { "voxel", "lower-node tile (8^3 voxels) at",
                                  "upper-node tile (128^3 voxels) at",
                                  "root tile (4096^3 voxels) at" };
    std::string s = std::string(what[l.level]) + " (" + std::to_string(l.ijk[0]) + ", " +
                    std::to_string(l.ijk[1]) + ", " + std::to_string(l.ijk[2]) + ")";
    if (!l.reachable)
        s += ", in a node no root tile reaches";
    return s;
}

ValueScan scan_values(const ValidatedGrid &grid) {
    const ValueStats &v = grid.values();
    ValueScan s;
    s.value_count = v.value_count;
    s.nan_count = v.nan_count;
    s.posinf_count = v.posinf_count;
    s.neginf_count = v.neginf_count;
    s.negative_count = v.negative_count;
    s.finite_max = v.finite_max;
    s.has_nan = v.first_nan != ValueStats::NONE;
    s.has_inf = v.first_inf != ValueStats::NONE;
    s.has_negative = v.first_negative != ValueStats::NONE;
    if (s.has_nan) s.first_nan = locate_value(grid, v.first_nan);
    if (s.has_inf) s.first_inf = locate_value(grid, v.first_inf);
    if (s.has_negative) s.first_negative = locate_value(grid, v.first_negative);
    return s;
}

std::string describe_invalid_values(const ValueScan &s) {
    std::string msg = std::to_string(s.nan_count) + " NaN";
    if (s.has_nan) msg += " (first: " + describe_location(s.first_nan) + ")";
    msg += ", " + std::to_string(s.posinf_count) + " +Inf and " +
           std::to_string(s.neginf_count) + " -Inf values";
    if (s.has_inf) msg += " (first infinite: " + describe_location(s.first_inf) + ")";
    return msg;
}

namespace {

/// Encodes a quantized leaf's 512 values again at its code width (see
/// sanitize_values); NanoVDB's encoder without dithering
void encode_quantized_leaf(uint8_t *leaf, const float *values, uint32_t log2_bits) {
    const uint32_t bits = 1u << log2_bits, per_word_bits = 5u - log2_bits;
    const uint32_t top = (1u << bits) - 1u;
    float lo = values[0], hi = values[0];
    for (uint32_t n = 1; n < 512; ++n) {
        lo = std::min(lo, values[n]);
        hi = std::max(hi, values[n]);
    }
    const float quantum = (hi - lo) / float(top);
    uint8_t *table = leaf + layout::GRID_TYPE_CONSTANTS_FPN.leaf_off_table;
    std::memcpy(table - layout::LEAF_TABLE_NEG_OFF_MINIMUM, &lo, 4);
    std::memcpy(table - layout::LEAF_TABLE_NEG_OFF_QUANTUM, &quantum, 4);
    std::memset(table, 0, size_t(64) << log2_bits);
    for (uint32_t n = 0; n < 512; ++n) {
        uint32_t code = 0;
        if (quantum > 0.f)
            code = uint32_t(std::min(float(top), std::nearbyint((values[n] - lo) / quantum)));
        uint8_t *word = table + 4 * (n >> per_word_bits);
        const uint32_t w = load<uint32_t>(word) |
                           (code << ((n & ((1u << per_word_bits) - 1u)) << log2_bits));
        std::memcpy(word, &w, 4);
    }
}

} // namespace

SanitizeResult sanitize_values(ValidatedGrid &grid, const SanitizeOptions &options) {
    const ValueStats &before = grid.values();
    const bool any_finite = before.finite_max >= before.finite_min;
    // With clamp_negative every negative becomes 0, so the largest value left
    // is at least 0.
    const float pos_repl = !any_finite ? 0.f
                         : options.clamp_negative ? std::max(before.finite_max, 0.f)
                                                  : before.finite_max;
    const float neg_repl = options.clamp_negative || !any_finite ? 0.f : before.finite_min;
    SanitizeResult r;
    auto repair = [&](float v) {
        if (std::isnan(v)) { ++r.nan; return 0.f; }
        if (v == std::numeric_limits<float>::infinity()) { ++r.posinf; return pos_repl; }
        if (v == -std::numeric_limits<float>::infinity()) { ++r.neginf; return neg_repl; }
        if (v < 0.f && options.clamp_negative) { ++r.negative; return 0.f; }
        return v;
    };
    ValueAccumulator after;
    const GridSummary &s = grid.summary();
    const ValueCodec codec(s.grid_type);
    const uint32_t channels = codec.channels();
    const bool half = codec.type().codec == layout::LeafCodec::Half;
    // Writes v at p as the type stores it (NaN != 0 too: compare bits)
    auto store = [&](uint8_t *p, float v) {
        if (half) {
            const uint16_t h = float_to_half(v); // v is a half or a replacement
            std::memcpy(p, &h, 2);                // (finite_max/min of halves, 0)
        } else {
            std::memcpy(p, &v, 4);
        }
    };
    for_each_tile_value(grid, [&](uint8_t *p, uint64_t byte) {
        float v[3] = { 0.f, 0.f, 0.f };
        codec.tile(p, v);
        for (uint32_t k = 0; k < channels; ++k) {
            const float w = repair(v[k]);
            if (std::memcmp(&w, &v[k], 4) != 0)
                store(p + 4 * k, w);
            after.add(w, byte);
        }
    });
    std::vector<float> leaf_min(s.node_count[0], std::numeric_limits<float>::infinity()),
                       leaf_max(s.node_count[0], -std::numeric_limits<float>::infinity());
    uint8_t *buf = ValueRewriter::data(grid);
    std::vector<float> values(512 * channels);
    for (uint64_t n = 0; n < s.node_count[0]; ++n) {
        uint8_t *leaf = buf + grid.leaf_byte(n);
        codec.leaf(leaf, values.data());
        bool changed = false;
        for (uint32_t k = 0; k < 512 * channels; ++k) {
            const float w = repair(values[k]);
            if (std::memcmp(&w, &values[k], 4) == 0)
                continue;
            changed = true;
            values[k] = w;
            if (!codec.quantized())
                store(leaf + codec.leaf_value_offset(k / channels) + 4 * (k % channels), w);
        }
        if (changed && codec.quantized()) {
            encode_quantized_leaf(leaf, values.data(), codec.log2_bits(leaf));
            codec.leaf(leaf, values.data()); // the values lookups now return
        }
        for (uint32_t k = 0; k < 512 * channels; ++k) {
            after.add(values[k], ValueStats::leaf_value_key(n, k / channels));
            leaf_min[size_t(n)] = std::min(leaf_min[size_t(n)], values[k]);
            leaf_max[size_t(n)] = std::max(leaf_max[size_t(n)], values[k]);
        }
    }
    ValueRewriter::set_values(grid, after.finish(), std::move(leaf_min), std::move(leaf_max));
    return r;
}

std::vector<std::string> apply_value_policy(ValidatedGrid &grid, const std::string &grid_name,
                                            InvalidValues policy) {
    const ValueStats &v = grid.values();
    const std::string &path = grid.path();
    if (v.all_finite() && v.negative_count == 0)
        return {};
    if (policy == InvalidValues::Clamp) {
        SanitizeResult r = sanitize_values(grid);
        return { "\"" + path + "\": grid \"" + grid_name + "\": replaced " +
                 std::to_string(r.nan) + " NaN by 0, " + std::to_string(r.posinf) +
                 " +Inf by the largest finite value, " + std::to_string(r.neginf) + " -Inf and " +
                 std::to_string(r.negative) + " negative values by 0 (invalid_values=clamp)." };
    }
    const ValueScan scan = scan_values(grid);
    if (!v.all_finite())
        fail(path, "grid \"" + grid_name + "\" contains " + describe_invalid_values(scan) +
                       "; only finite values can be rendered. Set invalid_values=\"clamp\" to "
                       "replace NaN by 0, +Inf by the largest finite value and -Inf and "
                       "negative values by 0.");
    return { "\"" + path + "\": grid \"" + grid_name + "\" contains " +
             std::to_string(scan.negative_count) + " negative values (first: " +
             describe_location(scan.first_negative) +
             "); a negative density makes no physical sense. Set invalid_values=\"clamp\" "
             "to replace them by 0." +
             (grid.summary().grid_class == 1
                  ? std::string(" The grid is a level set (signed distances, negative inside), "
                                "not a density: make it a fog volume with `vdb2nvdb " + path +
                                " fog.nvdb` (nanovdb-render does that itself).")
                  : std::string()) };
}

} // namespace nanovdb_loader
