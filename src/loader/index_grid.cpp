// src/loader/index_grid.cpp -- take_blind_values() and make_index_grid()
// (see index_grid.h).

#include <nanovdb_loader/index_grid.h>

#include "detail.h"
#include "tree_view.h"
#include "value_codec.h"

#include <cstring>

namespace nanovdb_loader {

namespace {

using namespace detail;

// GridData beyond what PNanoVDB 32.4 names (NanoVDB 32.6: GridData's
// mBlindMetadataOffset, mBlindMetadataCount, mData1 = an index grid's value
// count including the background), and GridBlindMetaData (288 bytes)
constexpr uint32_t GRID_OFF_BLIND_METADATA_OFFSET = 640;
constexpr uint32_t GRID_OFF_BLIND_METADATA_COUNT = 648;
constexpr uint32_t GRID_OFF_DATA1 = 656;
constexpr uint32_t BLIND_SIZE = 288;
constexpr uint32_t BLIND_OFF_DATA_OFFSET = 0;  ///< int64, relative to the record
constexpr uint32_t BLIND_OFF_VALUE_COUNT = 8;  ///< uint64
constexpr uint32_t BLIND_OFF_VALUE_SIZE = 16;  ///< uint32 bytes per value
constexpr uint32_t BLIND_OFF_DATA_TYPE = 28;   ///< uint32, a GridType (1: float)
constexpr uint32_t BLIND_OFF_NAME = 32;        ///< char[256]
constexpr uint32_t BLIND_NAME_SIZE = 256;

/// A blind channel as read from its record
struct Channel {
    std::string name;
    uint64_t data = 0, value_count = 0; ///< byte offset in the grid; values
    uint32_t value_size = 0, data_type = 0;
};

} // namespace

IndexGridValues take_blind_values(const std::string &path, uint8_t *grid, uint64_t bytes,
                                  const BlindSelection &sel, uint64_t &tree_bytes) {
    const std::string name = fixed_string(grid + layout::GRID_OFF_GRID_NAME, layout::GRID_NAME_SIZE);
    const std::string who = "index grid \"" + name + "\"";
    const int64_t meta = load<int64_t>(grid + GRID_OFF_BLIND_METADATA_OFFSET);
    const uint32_t count = load<uint32_t>(grid + GRID_OFF_BLIND_METADATA_COUNT);
    if (count == 0)
        fail(path, who + " has no blind data: the values its indices stand for are not in "
                         "the file (fVDB and Warp store them in a blind channel of floats)");
    if (meta < int64_t(layout::GRID_HEADER_SIZE) || uint64_t(meta) > bytes ||
        uint64_t(count) > (bytes - uint64_t(meta)) / BLIND_SIZE)
        fail(path, who + ": its " + std::to_string(count) + " blind data records at byte " +
                       std::to_string(meta) + " lie outside the " + std::to_string(bytes) +
                       "-byte grid");
    std::vector<Channel> channels;
    std::string names;
    for (uint32_t i = 0; i < count; ++i) {
        const uint8_t *r = grid + meta + uint64_t(i) * BLIND_SIZE;
        Channel c;
        c.name = fixed_string(r + BLIND_OFF_NAME, BLIND_NAME_SIZE);
        const int64_t off = load<int64_t>(r + BLIND_OFF_DATA_OFFSET);
        c.value_count = load<uint64_t>(r + BLIND_OFF_VALUE_COUNT);
        c.value_size = load<uint32_t>(r + BLIND_OFF_VALUE_SIZE);
        c.data_type = load<uint32_t>(r + BLIND_OFF_DATA_TYPE);
        const uint64_t at = uint64_t(meta) + uint64_t(i) * BLIND_SIZE;
        if ((off < 0 && uint64_t(-(off + 1)) + 1 > at) || (off >= 0 && uint64_t(off) > bytes - at) ||
            (c.value_size != 0 && c.value_count > (bytes - (at + uint64_t(off))) / c.value_size))
            fail(path, who + ": blind channel \"" + c.name + "\" (" + std::to_string(c.value_count) +
                           " values of " + std::to_string(c.value_size) +
                           " bytes) lies outside the " + std::to_string(bytes) + "-byte grid");
        c.data = at + uint64_t(off);
        names += (names.empty() ? "\"" : ", \"") + c.name + "\"";
        channels.push_back(c);
    }
    auto is_fvdb = [](const Channel &c) {
        return c.value_size == 1 && c.name.rfind("fvdb_jdata", 0) == 0 &&
               c.name.size() >= 7 && c.name.compare(c.name.size() - 7, 7, "float32") == 0;
    };
    auto is_float = [](const Channel &c) { return c.data_type == 1 && c.value_size == 4; };
    const Channel *chosen = nullptr;
    for (const Channel &c : channels)
        if (sel.channel.empty() ? (is_float(c) || is_fvdb(c)) : c.name == sel.channel) {
            chosen = &c;
            break;
        }
    if (!chosen)
        fail(path, who + (sel.channel.empty()
                              ? std::string(" has no blind channel of floats")
                              : " has no blind channel \"" + sel.channel + "\"") +
                       " (its channels: " + names + ")");
    const Channel &c = *chosen;
    const uint64_t indices = load<uint64_t>(grid + GRID_OFF_DATA1); // with the background
    IndexGridValues out;
    const float *floats = nullptr;
    uint64_t rows = 0, row_floats = 1;
    if (is_fvdb(c)) {
        // int64 header: ndim, then the shape [N, d1, ...]; rows are indices 1..N
        const uint64_t n = c.value_count;
        const uint8_t *p = grid + c.data;
        const int64_t ndim = n >= 8 ? load<int64_t>(p) : 0;
        if (ndim < 1 || ndim > 8 || n < 8 * uint64_t(1 + ndim))
            fail(path, who + ": blind channel \"" + c.name + "\" does not start with an fVDB "
                             "tensor header (ndim = " + std::to_string(ndim) + ")");
        std::string shape;
        for (int64_t d = 0; d < ndim; ++d) {
            const int64_t extent = load<int64_t>(p + 8 * (1 + d));
            if (extent < 0 || extent > int64_t(1) << 40)
                fail(path, who + ": blind channel \"" + c.name + "\" has a tensor extent of " +
                               std::to_string(extent));
            shape += (d ? ", " : "") + std::to_string(extent);
            if (d == 0)
                rows = uint64_t(extent);
            else
                row_floats *= uint64_t(extent);
        }
        const uint64_t header = 8 * uint64_t(1 + ndim);
        if (row_floats == 0 || rows > (n - header) / 4 / row_floats ||
            header + 4 * rows * row_floats != n)
            fail(path, who + ": blind channel \"" + c.name + "\" holds " + std::to_string(n) +
                           " bytes, not the " + std::to_string(header) + "-byte header and the "
                           "floats of its shape [" + shape + "]");
        floats = reinterpret_cast<const float *>(p + header);
        out.note = "blind channel \"" + c.name + "\" (fVDB tensor [" + shape + "])";
    } else {
        if (!is_float(c))
            fail(path, who + ": blind channel \"" + c.name + "\" does not hold floats (type " +
                           grid_type_name(c.data_type) + ", " + std::to_string(c.value_size) +
                           "-byte values)");
        floats = reinterpret_cast<const float *>(grid + c.data);
        rows = c.value_count;
        out.note = "blind channel \"" + c.name + "\" (" + std::to_string(rows) + " floats)";
        if (indices != 0 && rows == indices) { // the background's value first
            std::memcpy(&out.background[0], floats, 4);
            out.background[1] = out.background[2] = out.background[0];
            ++floats;
            --rows;
        }
    }
    if (sel.component >= row_floats)
        fail(path, who + ": blind channel \"" + c.name + "\" holds " +
                       std::to_string(row_floats) + " float(s) per value; component " +
                       std::to_string(sel.component) + " does not exist");
    out.values.resize(size_t(rows));
    for (uint64_t r = 0; r < rows; ++r)
        std::memcpy(&out.values[size_t(r)], floats + r * row_floats + sel.component, 4);
    if (row_floats > 1)
        out.note += ", component " + std::to_string(sel.component) + " of " +
                    std::to_string(row_floats);

    // The tree ends where the blind data records begin (NanoVDB writes them
    // after the leaves); validation checks that every node lies before it
    tree_bytes = uint64_t(meta);
    store<uint64_t>(grid + layout::GRID_OFF_GRID_SIZE, tree_bytes);
    store<uint64_t>(grid + GRID_OFF_BLIND_METADATA_OFFSET, 0);
    store<uint32_t>(grid + GRID_OFF_BLIND_METADATA_COUNT, 0);
    return out;
}

MadeIndexGrid make_index_grid(const ValidatedGrid &grid) {
    const GridSummary &s = grid.summary();
    const std::string &path = grid.path();
    const ValueCodec codec(s.grid_type, &grid.index_values());
    if (codec.indexed())
        fail(path, "grid \"" + s.name + "\" is an index grid already");
    const uint32_t channels = codec.channels();
    const TreeView view(grid);
    // Index 0 stands for the background (a scalar grid's in every channel)
    float bg[3] = { 0.f, 0.f, 0.f };
    codec.tile(grid.data() + view.background(), bg);
    if (channels == 1)
        bg[1] = bg[2] = bg[0];
    const uint8_t *src = grid.data();
    const layout::GridTypeConstants &ci = layout::GRID_TYPE_CONSTANTS_ONINDEX;
    const uint64_t tiles = view.tile_count();
    const uint64_t n_upper = s.node_count[2], n_lower = s.node_count[1], n_leaf = s.node_count[0];

    // The layout: header, tree, root and tiles, then the node arrays
    const uint64_t root = layout::GRID_HEADER_SIZE;
    const uint64_t upper = root + ci.root_size + tiles * ci.root_tile_size;
    const uint64_t lower = upper + n_upper * ci.upper_size;
    const uint64_t leaves = lower + n_lower * ci.lower_size;
    const uint64_t end = leaves + n_leaf * ci.leaf_size;
    MadeIndexGrid out;
    std::vector<uint8_t> &b = out.bytes;
    b.assign(size_t(end), 0);
    auto new_node = [&](int level, uint64_t old_byte) {
        const uint64_t i = view.node_index(level, old_byte);
        return level == 2 ? upper + i * ci.upper_size
               : level == 1 ? lower + i * ci.lower_size
                            : leaves + i * ci.leaf_size;
    };

    // Indices in the documented order: active root tiles, upper, lower
    // tiles, then the leaves' active voxels
    std::vector<float> &values = out.values.values;
    out.values.background = { bg[0], bg[1], bg[2] };
    out.values.channels = channels;
    auto is_background = [&](const float *v) {
        for (uint32_t k = 0; k < channels; ++k)
            if (!(v[k] == bg[k] || std::memcmp(&v[k], &bg[k], 4) == 0))
                return false;
        return true;
    };
    auto differs = [&](const float *v) {
        if (!is_background(v))
            ++out.inactive_differing;
    };
    // A value's `channels` floats appended: its index
    auto take = [&](const float *v) {
        values.insert(values.end(), v, v + channels);
        const uint64_t count = values.size() / channels;
        if (count >= (uint64_t(1) << 32) - 1)
            fail(path, "grid \"" + s.name + "\" has 2^32 - 1 active values or more: beyond an "
                                            "index grid's 32-bit indices here");
        return count;
    };
    auto tile_value = [&](uint64_t byte, float *v) { codec.tile(src + byte, v); };

    std::memcpy(b.data(), src, layout::GRID_SIZE); // GridData, then patched
    store<uint32_t>(&b[layout::GRID_OFF_GRID_TYPE], layout::GRID_TYPE_ONINDEX);
    store<uint64_t>(&b[layout::GRID_OFF_GRID_SIZE], end);
    store<uint64_t>(&b[layout::GRID_OFF_CHECKSUM], ~uint64_t(0)); // none
    store<uint64_t>(&b[GRID_OFF_BLIND_METADATA_OFFSET], 0);
    store<uint32_t>(&b[GRID_OFF_BLIND_METADATA_COUNT], 0);
    // TreeData: the same counts, the new offsets (relative to the tree)
    const uint64_t tree = layout::GRID_SIZE;
    std::memcpy(&b[tree], src + tree, layout::TREE_SIZE);
    store<uint64_t>(&b[tree + layout::TREE_OFF_NODE_OFFSET_ROOT], root - tree);
    store<uint64_t>(&b[tree + layout::TREE_OFF_NODE_OFFSET_UPPER], n_upper ? upper - tree : 0);
    store<uint64_t>(&b[tree + layout::TREE_OFF_NODE_OFFSET_LOWER], n_lower ? lower - tree : 0);
    store<uint64_t>(&b[tree + layout::TREE_OFF_NODE_OFFSET_LEAF], n_leaf ? leaves - tree : 0);

    // Root: its box and tile count; background index 0; no stats
    const uint64_t src_root = uint64_t(s.root_word) * 4;
    std::memcpy(&b[root], src + src_root, layout::ROOT_OFF_TABLE_SIZE + 4);
    for (uint32_t t = 0; t < tiles; ++t) {
        const uint64_t at = root + ci.root_size + uint64_t(t) * ci.root_tile_size;
        const uint64_t from = view.tile(t);
        std::memcpy(&b[at], src + from, layout::ROOT_TILE_OFF_STATE + 4); // key, child, state
        const uint64_t child = view.tile_child(t);
        if (child != 0) {
            store<uint64_t>(&b[at + layout::ROOT_TILE_OFF_CHILD], uint64_t(int64_t(new_node(2, child)) - int64_t(root)));
        } else {
            float v[3] = { 0.f, 0.f, 0.f };
            tile_value(view.tile_value(t), v);
            if (load<uint32_t>(src + from + layout::ROOT_TILE_OFF_STATE) != 0 || !is_background(v))
                store<uint64_t>(&b[at + ci.root_tile_off_value], take(v));
        }
    }
    // Internal nodes: header and masks as they are; children relocated,
    // active tiles indexed
    for (int level : { 2, 1 }) {
        const uint32_t table_count = level == 2 ? layout::UPPER_TABLE_COUNT : layout::LOWER_TABLE_COUNT;
        const uint32_t off_min = level == 2 ? ci.upper_off_min : ci.lower_off_min,
                       off_table = level == 2 ? ci.upper_off_table : ci.lower_off_table,
                       value_mask = level == 2 ? layout::UPPER_OFF_VALUE_MASK : layout::LOWER_OFF_VALUE_MASK;
        for (uint64_t i = 0; i < s.node_count[level]; ++i) {
            const uint64_t from = view.node(level, i), at = new_node(level, from);
            std::memcpy(&b[at], src + from, off_min);
            for (uint32_t e = 0; e < table_count; ++e) {
                uint8_t *entry = &b[at + off_table + 8 * uint64_t(e)];
                if (view.child_bit(level, from, e)) {
                    store<uint64_t>(entry, uint64_t(int64_t(new_node(level - 1, view.child(level, from, e))) -
                                            int64_t(at)));
                    continue;
                }
                float v[3] = { 0.f, 0.f, 0.f };
                tile_value(view.entry(level, from, e), v);
                if (((load<uint32_t>(src + from + value_mask + 4 * (e >> 5)) >> (e & 31)) & 1u) ||
                    !is_background(v))
                    store<uint64_t>(entry, take(v));
            }
        }
    }
    // Leaves: box, flags (no stats) and mask; the first index and the
    // prefix sums of the mask's popcounts
    std::vector<float> decoded(layout::LEAF_TABLE_COUNT * channels);
    for (uint64_t i = 0; i < n_leaf; ++i) {
        const uint64_t from = view.node(0, i), at = leaves + i * ci.leaf_size;
        std::memcpy(&b[at], src + from, ci.leaf_off_table);
        b[at + layout::LEAF_OFF_BBOX_DIF_AND_FLAGS + 3] &= uint8_t(~0x10u);
        codec.leaf(src + from, decoded.data());
        const uint64_t first = values.size() / channels + 1;
        uint64_t prefix = 0, active = 0;
        for (uint32_t w = 0; w < 8; ++w) {
            if (w > 0)
                prefix |= active << (9 * (w - 1));
            const uint64_t mask = load<uint64_t>(src + from + layout::LEAF_OFF_VALUE_MASK + 8 * w);
            for (uint32_t k = 0; k < 64; ++k) {
                const uint32_t n = 64 * w + k;
                if ((mask >> k) & 1u)
                    take(&decoded[size_t(channels) * n]);
                else
                    differs(&decoded[size_t(channels) * n]);
            }
            active += uint64_t(__builtin_popcountll(mask));
        }
        store<uint64_t>(&b[at + ci.leaf_off_table], first);
        store<uint64_t>(&b[at + ci.leaf_off_table + layout::ONINDEX_LEAF_TABLE_OFF_PREFIX_SUM], prefix);
    }
    store<uint64_t>(&b[GRID_OFF_DATA1], values.size() / channels + 1);
    out.values.note = std::to_string(values.size() / channels) + " active values of a " +
                      grid_type_name(s.grid_type) + " grid" +
                      (s.grid_type == layout::GRID_TYPE_FLOAT ? ""
                       : channels == 3                         ? ", three floats each"
                                                               : ", decoded to floats");
    return out;
}

} // namespace nanovdb_loader
