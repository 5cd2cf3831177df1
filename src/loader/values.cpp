// src/loader/values.cpp -- the value policy (see values.h).

#include <nanovdb_loader/values.h>

#include "detail.h"
#include "tree_view.h"
#include "value_codec.h"
#include "value_rewriter.h"
#include "value_stats.h"

#include <cmath>
#include <limits>

namespace nanovdb_loader {

namespace {

using namespace detail;

/// The first voxel of every node, from the root keys down (first path wins;
/// every root tile in table order, a later one repeating a key too); nodes
/// that no root tile reaches keep `set == false`
struct NodeOrigins {
    struct Origin { int32_t ijk[3]; bool set; };
    std::vector<Origin> origin[3]; // leaf, lower, upper

    explicit NodeOrigins(const TreeView &view) {
        for (int l = 0; l < 3; ++l)
            origin[l].assign(view.node_count(l), Origin{ { 0, 0, 0 }, false });
        for (uint32_t t = 0; t < view.tile_count(); ++t) {
            const uint64_t child = view.tile_child(t);
            if (child == 0) continue;
            Origin &o = origin[2][view.node_index(2, child)];
            if (o.set) continue;
            view.tile_origin(t, o.ijk);
            o.set = true;
        }
        for (int level : { 2, 1 }) {
            for (uint64_t n = 0; n < view.node_count(level); ++n) {
                const Origin &o = origin[level][size_t(n)];
                if (!o.set) continue; // unreachable: its children keep no origin from it
                const uint64_t node = view.node(level, n);
                for (uint32_t e = 0; e < view.level(level).table_count; ++e) {
                    if (!view.child_bit(level, node, e))
                        continue;
                    const uint64_t below = view.node_index(level - 1, view.child(level, node, e));
                    Origin &child = origin[level - 1][size_t(below)];
                    if (child.set) continue;
                    view.entry_origin(level, o.ijk, e, child.ijk);
                    child.set = true;
                }
            }
        }
    }
};

/// loc.level and loc.ijk of entry e of node n (at byte `node`) of `level`
void locate_entry(const TreeView &view, int level, size_t n, uint64_t node, uint32_t e,
                  ValueLocation &loc) {
    const NodeOrigins origins(view);
    const NodeOrigins::Origin &o = origins.origin[level][n];
    int32_t base[3];
    if (o.set) {
        for (int k = 0; k < 3; ++k) base[k] = o.ijk[k];
    } else { // the node's own bbox minimum, rounded down to the node size
        const uint32_t m = level == 0 ? 7u : level == 1 ? 127u : 4095u;
        for (int k = 0; k < 3; ++k)
            base[k] = int32_t(load<uint32_t>(view.data() + node + 4 * k) & ~m);
        loc.reachable = false;
    }
    loc.level = uint32_t(level);
    view.entry_origin(level, base, e, loc.ijk);
}

} // namespace

ValueLocation locate_value(const ValidatedGrid &grid, uint64_t key) {
    const TreeView view(grid);
    ValueLocation loc;
    if (key & ValueStats::LEAF_VALUE) { // leaf index << 9 | n
        const uint64_t leaf = (key & ~ValueStats::LEAF_VALUE) >> 9, node = view.node(0, leaf);
        const uint32_t n = uint32_t(key & 511u);
        loc.byte = node + ValueCodec(grid.summary().grid_type).leaf_value_offset(n);
        locate_entry(view, 0, size_t(leaf), node, n, loc);
        return loc;
    }
    const uint64_t byte = key;
    loc.byte = byte;
    const uint64_t tiles = view.tile(0), tile_size = view.tile(1) - tiles;
    if (byte >= tiles && byte < view.tile(view.tile_count())) {
        loc.level = 3;
        view.tile_origin(uint32_t((byte - tiles) / tile_size), loc.ijk);
        return loc;
    }
    for (int level : { 2, 1 }) {
        const GridSummary &s = grid.summary();
        if (s.node_count[level] == 0 || byte < s.node_begin[level] || byte >= s.node_end[level])
            continue;
        const NodeLevel &l = view.level(level);
        const uint64_t n = view.node_index(level, byte), node = view.node(level, n);
        locate_entry(view, level, size_t(n), node,
                     uint32_t((byte - node - l.table_off) / l.table_stride), loc);
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
    const ValueCodec codec(s.grid_type, &grid.index_values());
    const uint32_t channels = codec.channels();
    const bool half = codec.type().codec == layout::LeafCodec::Half;
    // Writes channel k of the value at p as the type stores it (NaN != 0
    // too: compare bits); index grids: into their values, at the index
    // stored at p
    auto store = [&](uint8_t *p, uint32_t k, float v) {
        if (codec.indexed()) {
            if (float *slot = codec.indexed_slot(load<uint64_t>(p)))
                slot[k] = v;
            else
                ValueRewriter::set_index_background(grid, k, v);
        } else if (half) {
            const uint16_t h = float_to_half(v); // v is a half or a replacement
            std::memcpy(p, &h, 2);                // (finite_max/min of halves, 0)
        } else {
            std::memcpy(p + 4 * k, &v, 4);
        }
    };
    uint8_t *buf = ValueRewriter::data(grid);
    TreeView(grid).for_each_tile_value([&](uint64_t byte, int, uint32_t) {
        uint8_t *p = buf + byte;
        float v[3] = { 0.f, 0.f, 0.f };
        codec.tile(p, v);
        for (uint32_t k = 0; k < channels; ++k) {
            const float w = repair(v[k]);
            if (std::memcmp(&w, &v[k], 4) != 0)
                store(p, k, w);
            after.add(w, byte);
        }
    });
    std::vector<float> leaf_min(s.node_count[0], std::numeric_limits<float>::infinity()),
                       leaf_max(s.node_count[0], -std::numeric_limits<float>::infinity());
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
            if (codec.indexed()) {
                if (float *slot = codec.indexed_slot(onindex_leaf_index(leaf, k / channels)))
                    slot[k % channels] = w;
                else
                    ValueRewriter::set_index_background(grid, k % channels, w);
            } else if (!codec.quantized())
                store(leaf + codec.leaf_value_offset(k / channels), k % channels, w);
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
