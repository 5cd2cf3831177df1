// src/loader/validation.cpp -- validate_grid() (see validation.h), in
// four steps: the grid header, the regions of the tree (node arrays, root,
// disjointness), the header fields, then one walk over the tree (through
// tree_view.h) that checks every root key and child offset and accumulates
// the values.

#include <nanovdb_loader/validation.h>

#include "detail.h"
#include "tree_view.h"
#include "value_codec.h"
#include "value_stats.h"

#include <algorithm>

#include <string>
#include <tuple>
#include <vector>

namespace nanovdb_loader {

namespace {

using namespace detail;

/// A node array of the tree: where it lies in the buffer
struct NodeArray {
    const char *name;
    uint64_t offset, count, node_size; ///< offset: relative to the tree
    uint64_t begin = 0;                ///< byte offset in the buffer
    /// FpN leaves only (node_size 0): each node's byte offset, and the end
    std::vector<uint64_t> starts;
    uint64_t variable_end = 0;

    uint64_t end() const { return node_size ? begin + count * node_size : variable_end; }
    /// Is byte offset t the start of a node of the array?
    bool is_node(uint64_t t) const {
        if (t < begin || t >= end())
            return false;
        if (node_size)
            return (t - begin) % node_size == 0;
        return std::binary_search(starts.begin(), starts.end(), t);
    }
};

/// Where the parts of the tree lie, once checked
struct TreeRegions {
    uint64_t grid_end;            ///< GridData.mGridSize
    uint64_t root;                ///< byte offset of the root node
    uint64_t table_size;          ///< root tiles
    NodeArray leaf, lower, upper;
};

/// Step 1: magic, version, type and size of the grid; returns mGridSize
uint64_t check_header(const std::string &path, const uint8_t *buf, uint64_t bytes,
                      std::string &name) {
    if (bytes >= kMaxGridBytes)
        fail(path, "grid buffer of " + std::to_string(bytes) +
                       " bytes is 16 GiB or more: beyond the reader's 32-bit word addresses");
    if (buf == nullptr || bytes < layout::GRID_HEADER_SIZE)
        fail(path, "grid buffer of " + std::to_string(bytes) +
                       " bytes is too small: a grid needs at least 736 bytes "
                       "(672-byte GridData + 64-byte TreeData)");
    const uint64_t magic = load<uint64_t>(buf + layout::GRID_OFF_MAGIC);
    if (is_byte_swapped_magic(magic))
        fail(path, "grid has a byte-swapped magic " + describe_magic(magic) +
                       ": only little-endian grids are supported");
    if (magic != layout::MAGIC_NUMBER && magic != layout::MAGIC_GRID)
        fail(path, "not a NanoVDB grid: magic " + describe_magic(magic) +
                       ", expected \"NanoVDB0\" or \"NanoVDB1\"");
    const uint32_t version = load<uint32_t>(buf + layout::GRID_OFF_VERSION);
    if (version_major(version) != layout::MAJOR_VERSION_NUMBER)
        fail(path, "grid version " + version_string(version) +
                       "; only major version 32 is supported");
    const uint32_t grid_type = load<uint32_t>(buf + layout::GRID_OFF_GRID_TYPE);
    name = fixed_string(buf + layout::GRID_OFF_GRID_NAME, layout::GRID_NAME_SIZE);
    if (!layout::value_type(grid_type))
        fail(path, "grid \"" + name + "\" has type " + grid_type_name(grid_type) +
                       ", which is not supported (supported types: " + supported_grid_types() +
                       ")");
    const uint64_t end = load<uint64_t>(buf + layout::GRID_OFF_GRID_SIZE);
    if (end > bytes)
        fail(path, "GridData.mGridSize = " + std::to_string(end) +
                       " bytes is larger than the " + std::to_string(bytes) + "-byte buffer");
    if (end < layout::GRID_HEADER_SIZE)
        fail(path, "GridData.mGridSize = " + std::to_string(end) +
                       " bytes is smaller than a grid's 736-byte header");
    return end;
}

/// FpN leaves, one after the other: each one's code width (1 to 16 bits)
/// gives its size, and each must lie inside the grid
void fpn_leaves(const std::string &path, const uint8_t *buf, uint64_t end, NodeArray &l) {
    const uint64_t tree = layout::GRID_SIZE;
    if (l.offset > end - tree)
        fail(path, "leaf node array at tree offset " + std::to_string(l.offset) +
                       " lies outside the " + std::to_string(end) + "-byte grid");
    l.begin = tree + l.offset;
    if (l.begin % layout::NODE_ALIGNMENT != 0)
        fail(path, "leaf node array at byte " + std::to_string(l.begin) +
                       " is not 32-byte aligned");
    l.starts.reserve(size_t(l.count));
    uint64_t at = l.begin;
    for (uint64_t n = 0; n < l.count; ++n) {
        if (end - at < layout::FPN_MIN_LEAF_SIZE)
            fail(path, "FpN leaf " + std::to_string(n) + " of " + std::to_string(l.count) +
                           " (byte " + std::to_string(at) + ") does not fit in the " +
                           std::to_string(end) + "-byte grid");
        const uint32_t flags = load<uint32_t>(buf + at + layout::LEAF_OFF_BBOX_DIF_AND_FLAGS) >> 24;
        if ((flags >> 5) > 4)
            fail(path, "FpN leaf " + std::to_string(n) + " (byte " + std::to_string(at) +
                           ") has a code width of " + std::to_string(1u << (flags >> 5)) +
                           " bits (flags " + std::to_string(flags) +
                           "); FpN codes are 1, 2, 4, 8 or 16 bits");
        const uint64_t size = layout::fpn_leaf_size(flags);
        if (size > end - at)
            fail(path, "FpN leaf " + std::to_string(n) + " (byte " + std::to_string(at) + ", " +
                           std::to_string(size) + " bytes) extends past the end of the " +
                           std::to_string(end) + "-byte grid");
        l.starts.push_back(at);
        at += size;
    }
    l.variable_end = at;
}

/// Step 2: the node arrays and the root with its tile table lie inside the
/// grid, aligned, and do not overlap each other or the header
TreeRegions check_regions(const std::string &path, const uint8_t *buf, uint64_t end,
                          const ValueCodec &codec) {
    const layout::GridTypeConstants &c = codec.constants();
    const uint64_t tree = layout::GRID_SIZE;
    const uint8_t *t = buf + tree;
    TreeRegions g{ end, 0, 0,
                   { "leaf", load<uint64_t>(t + layout::TREE_OFF_NODE_OFFSET_LEAF),
                     load<uint32_t>(t + layout::TREE_OFF_NODE_COUNT_LEAF),
                     codec.variable_leaf_size() ? 0 : c.leaf_size, 0, {}, 0 },
                   { "lower", load<uint64_t>(t + layout::TREE_OFF_NODE_OFFSET_LOWER),
                     load<uint32_t>(t + layout::TREE_OFF_NODE_COUNT_LOWER), c.lower_size, 0, {}, 0 },
                   { "upper", load<uint64_t>(t + layout::TREE_OFF_NODE_OFFSET_UPPER),
                     load<uint32_t>(t + layout::TREE_OFF_NODE_COUNT_UPPER), c.upper_size, 0, {}, 0 } };
    for (NodeArray *l : { &g.leaf, &g.lower, &g.upper }) {
        if (l->count == 0)
            continue; // offset unused (writers leave it 0 or point at the end)
        const uint64_t room = end - tree;
        if (l->node_size == 0) { // FpN leaves: each as long as its code width
            fpn_leaves(path, buf, end, *l);
            continue;
        }
        if (l->offset > room || l->count * l->node_size > room - l->offset)
            fail(path, std::string(l->name) + " node array (" + std::to_string(l->count) +
                           " nodes of " + std::to_string(l->node_size) +
                           " bytes at tree offset " + std::to_string(l->offset) +
                           ") does not fit in the " + std::to_string(end) + "-byte grid");
        l->begin = tree + l->offset;
        if (l->begin % layout::NODE_ALIGNMENT != 0)
            fail(path, std::string(l->name) + " node array at byte " +
                           std::to_string(l->begin) + " is not 32-byte aligned");
    }

    // Root node and its tile table.
    const uint64_t root_off = load<uint64_t>(t + layout::TREE_OFF_NODE_OFFSET_ROOT);
    if (root_off > end - tree || c.root_size > end - tree - root_off)
        fail(path, "root node offset " + std::to_string(root_off) +
                       " (relative to the tree at byte 672) lies outside the " +
                       std::to_string(end) + "-byte grid");
    g.root = tree + root_off;
    if (g.root % layout::NODE_ALIGNMENT != 0)
        fail(path, "root node at byte " + std::to_string(g.root) + " is not 32-byte aligned");
    g.table_size = load<uint32_t>(buf + g.root + layout::ROOT_OFF_TABLE_SIZE);
    if (g.table_size > (end - g.root - c.root_size) / c.root_tile_size)
        fail(path, "root tile table of " + std::to_string(g.table_size) +
                       " tiles (table_size; root at byte " + std::to_string(g.root) +
                       ") extends past the end of the " + std::to_string(end) + "-byte grid");

    // The header, the root with its tile table and the three node arrays are
    // disjoint (NanoVDB writes them back to back). Were they allowed to
    // overlap, one node's bytes would also be read as a node of another level
    // or as the root: a child offset could then point at its own parent, or a
    // leaf's values be read as child offsets. Lookups could not leave the
    // buffer even so (every node a child offset reaches is checked in step
    // 3), but no writer produces such a grid, so it is reported as corrupt.
    struct Region { const char *name; uint64_t begin, end; };
    const Region regions[] = {
        { "grid and tree header", 0, layout::GRID_HEADER_SIZE },
        { "root node and its tile table", g.root,
          g.root + c.root_size + g.table_size * c.root_tile_size },
        { "upper node array", g.upper.begin, g.upper.end() },
        { "lower node array", g.lower.begin, g.lower.end() },
        { "leaf node array", g.leaf.begin, g.leaf.end() },
    };
    auto span = [](const Region &x) {
        return "[" + std::to_string(x.begin) + ", " + std::to_string(x.end) + ")";
    };
    for (size_t a = 0; a < 5; ++a)
        for (size_t b = a + 1; b < 5; ++b) {
            const Region &x = regions[a], &y = regions[b];
            if (x.begin == x.end || y.begin == y.end)
                continue; // a level without nodes occupies nothing
            if (x.begin < y.end && y.begin < x.end)
                fail(path, std::string("the ") + y.name + " " + span(y) + " overlaps the " +
                               x.name + " " + span(x));
        }
    return g;
}

/**
 * Step 4: one walk over the tree in buffer order. Every root tile key must be
 * one a coordinate has, every child offset must point exactly at a node of
 * the level below; every value that is not a child goes to the accumulator.
 */
class TreeWalk {
public:
    TreeWalk(const std::string &path, const TreeView &view, const uint8_t *buf,
             const TreeRegions &g, const ValueCodec &codec, const IndexValues &index)
        : m_path(path), m_view(view), m_buf(buf), m_g(g), m_codec(codec), m_index(index) {}

    /// The smallest and largest value of every leaf (NaN skipped), in leaf
    /// array order
    std::vector<float> leaf_min, leaf_max;

    ValueStats run() {
        root_tiles();
        internal_nodes(2, m_g.upper, m_g.lower);
        internal_nodes(1, m_g.lower, m_g.leaf);
        m_view.for_each_tile_value([&](uint64_t at, int, uint32_t) { tile_value(at); });
        leaves();
        return m_values.finish();
    }

private:
    /// Root tiles: a key that no coordinate has, or a child offset that
    /// misses the upper nodes, is refused. (PNanoVDB follows a non-zero
    /// child, else reads the tile value.)
    void root_tiles() {
        for (uint32_t t = 0; t < m_view.tile_count(); ++t) {
            const uint64_t key = m_view.tile_key(t);
            if (key & UNUSED_KEY_BITS)
                fail(m_path, "root tile " + std::to_string(t) + " (byte " +
                                 std::to_string(m_view.tile(t)) + ") has key " + hex64(key) +
                                 " with " + describe_unused_key_bits(key & UNUSED_KEY_BITS) +
                                 " set: a key holds three 20-bit block coordinates in 21-bit "
                                 "fields, so no coordinate has this key (PNanoVDB never "
                                 "finds the tile; an index by block would)");
            const int64_t child = load<int64_t>(m_buf + m_view.tile(t) + layout::ROOT_TILE_OFF_CHILD);
            if (child != 0)
                check_child(m_g.upper, m_g.root, child, [&] {
                    return "root tile " + std::to_string(t) + " (key " + hex64(key) + ")";
                });
        }
    }

    /// Internal nodes of `level`: each child-mask bit selects a child offset
    /// (relative to the node) or, when clear, a tile value in the same entry
    void internal_nodes(int level, const NodeArray &nodes, const NodeArray &below) {
        for (uint64_t n = 0; n < nodes.count; ++n) {
            const uint64_t node = m_view.node(level, n);
            for (uint32_t e = 0; e < m_view.level(level).table_count; ++e) {
                if (!m_view.child_bit(level, node, e))
                    continue;
                check_child(below, node, load<int64_t>(m_buf + m_view.entry(level, node, e)), [&] {
                    return std::string(nodes.name) + " node " + std::to_string(n) + " (byte " +
                           std::to_string(node) + ") table entry " + std::to_string(e);
                });
            }
        }
    }

    /// A value outside the leaves (`channels` floats at byte `at`)
    void tile_value(uint64_t at) {
        if (m_codec.indexed())
            check_index(load<uint64_t>(m_buf + at), [&] {
                return "the tile value index at byte " + std::to_string(at);
            });
        float v[3] = { 0.f, 0.f, 0.f };
        m_codec.tile(m_buf + at, v);
        for (uint32_t k = 0; k < m_codec.channels(); ++k)
            m_values.add(v[k], at);
    }

    /// Leaves hold almost all values: a vectorizable pass per leaf (decoded
    /// first unless they are floats)
    void leaves() {
        leaf_min.resize(m_g.leaf.count);
        leaf_max.resize(m_g.leaf.count);
        const uint32_t channels = m_codec.channels();
        std::vector<float> decoded(layout::LEAF_TABLE_COUNT * channels);
        for (uint64_t n = 0; n < m_g.leaf.count; ++n) {
            const uint64_t leaf = m_view.node(0, n);
            if (m_codec.indexed())
                index_leaf(n, leaf);
            const float *values =
                reinterpret_cast<const float *>(m_buf + leaf + m_view.level(0).table_off);
            if (m_codec.type().codec != layout::LeafCodec::Float32) {
                m_codec.leaf(m_buf + leaf, decoded.data());
                values = decoded.data();
            }
            auto key = [n, channels](uint32_t k) {
                return ValueStats::leaf_value_key(n, k / channels);
            };
            std::tie(leaf_min[n], leaf_max[n]) =
                channels == 1
                    ? m_values.add_run<layout::LEAF_TABLE_COUNT>(values, key)
                    : m_values.add_run<layout::LEAF_TABLE_COUNT * 3>(values, key);
        }
    }

    /// Index grids: `index` must have a value (`who`: a callable naming it)
    template <typename Who> void check_index(uint64_t index, const Who &who) const {
        const IndexValues &iv = m_index;
        if (index > iv.count)
            fail(m_path, who() + " is " + std::to_string(index) + ", but the grid has " +
                             std::to_string(iv.count) + " values (indices 1 to " +
                             std::to_string(iv.count) + "; 0 is the background)");
    }

    /// An OnIndex leaf: its prefix sums match its mask (the device reads a
    /// voxel's index from them), and its indices have values
    void index_leaf(uint64_t n, uint64_t leaf) const {
        const uint8_t *p = m_buf + leaf;
        const layout::GridTypeConstants &c = layout::GRID_TYPE_CONSTANTS_ONINDEX;
        const uint64_t first = load<uint64_t>(p + c.leaf_off_table),
                       prefix = load<uint64_t>(p + c.leaf_off_table +
                                               layout::ONINDEX_LEAF_TABLE_OFF_PREFIX_SUM);
        auto who = [&] {
            return "OnIndex leaf " + std::to_string(n) + " (byte " + std::to_string(leaf) + ")";
        };
        uint64_t active = 0;
        for (uint32_t w = 0; w < 8; ++w) {
            if (w > 0 && ((prefix >> (9 * (w - 1))) & 511u) != active)
                fail(m_path, who() + " has prefix sum " +
                                 std::to_string((prefix >> (9 * (w - 1))) & 511u) +
                                 " before mask word " + std::to_string(w) + ", but its mask has " +
                                 std::to_string(active) + " active voxels there");
            active += uint64_t(__builtin_popcountll(load<uint64_t>(p + layout::LEAF_OFF_VALUE_MASK + 8 * w)));
        }
        if (active == 0)
            return;
        if (first == 0)
            fail(m_path, who() + " has active voxels but first value index 0 (the background's)");
        check_index(first + (active - 1), [&] {
            return who() + "'s last value index (first " + std::to_string(first) + " + " +
                   std::to_string(active) + " active voxels - 1)";
        });
    }

    /// `child` (relative to `from`) must point exactly at a node of `level`.
    /// `who` is a callable returning the parent's description: built only for
    /// a message (millions of children are checked in a large grid).
    template <typename Who>
    void check_child(const NodeArray &level, uint64_t from, int64_t child, const Who &who) {
        const uint64_t end = m_g.grid_end, array_end = level.end();
        if (level.count != 0 && child >= -int64_t(end) && child <= int64_t(end)) {
            const int64_t t = int64_t(from) + child; // |from|, |child| <= 2^34: no overflow
            if (t >= 0 && level.is_node(uint64_t(t)))
                return; // the common case, without building any message
        }
        const std::string msg_head = who() + " has child offset " + std::to_string(child);
        if (level.count == 0)
            fail(m_path, msg_head + ", but the grid has no " + level.name + " nodes");
        // Signed range check without overflow: target = from + child.
        if ((child < 0 && uint64_t(-(child + 1)) + 1 > from) ||
            (child >= 0 && uint64_t(child) > end - from))
            fail(m_path, msg_head + ": outside the " + std::to_string(end) + "-byte grid");
        const uint64_t target = child < 0 ? from - (uint64_t(-(child + 1)) + 1)
                                          : from + uint64_t(child);
        if (target < level.begin || target >= array_end)
            fail(m_path, msg_head + " (byte " + std::to_string(target) + "): outside the " +
                             level.name + " node array [" + std::to_string(level.begin) +
                             ", " + std::to_string(array_end) + ")");
        if (!level.is_node(target))
            fail(m_path, msg_head + " (byte " + std::to_string(target) +
                             "): misaligned, not at a " + level.name +
                             " node boundary (array at byte " + std::to_string(level.begin) +
                             (level.node_size ? ", stride " + std::to_string(level.node_size)
                                              : std::string(", FpN leaves")) + ")");
    }

    const std::string &m_path;
    const TreeView &m_view;
    const uint8_t *m_buf;
    const TreeRegions &m_g;
    const ValueCodec &m_codec;
    const IndexValues &m_index;
    ValueAccumulator m_values;
};

/// Step 3: the header fields the rest of the pipeline needs (and the walk
/// reads the tree with)
GridSummary summarize(const uint8_t *buf, const TreeRegions &g, const std::string &name,
                      const ValueCodec &codec) {
    const layout::GridTypeConstants &c = codec.constants();
    GridSummary s;
    const uint8_t *t = buf + layout::GRID_SIZE, *r = buf + g.root;
    s.grid_type = load<uint32_t>(buf + layout::GRID_OFF_GRID_TYPE);
    s.grid_class = load<uint32_t>(buf + layout::GRID_OFF_GRID_CLASS);
    s.name = name;
    s.root_word = uint32_t(g.root / 4);
    s.root_tile_count = uint32_t(g.table_size);
    for (int i = 0; i < 3; ++i) {
        s.bbox_min[i] = load<int32_t>(r + layout::ROOT_OFF_BBOX_MIN + 4 * i);
        s.bbox_max[i] = load<int32_t>(r + layout::ROOT_OFF_BBOX_MAX + 4 * i);
    }
    s.empty = s.bbox_min[0] > s.bbox_max[0] || s.bbox_min[1] > s.bbox_max[1] ||
              s.bbox_min[2] > s.bbox_max[2];
    s.background = codec.tile_bound(r + c.root_off_background);
    const uint8_t *map = buf + layout::GRID_OFF_MAP;
    for (int i = 0; i < 9; ++i) {
        s.map_mat[i] = load<double>(map + layout::MAP_OFF_MATD + 8 * i);
        s.map_inv[i] = load<double>(map + layout::MAP_OFF_INVMATD + 8 * i);
    }
    for (int i = 0; i < 3; ++i) {
        s.map_vec[i]    = load<double>(map + layout::MAP_OFF_VECD + 8 * i);
        s.voxel_size[i] = load<double>(buf + layout::GRID_OFF_VOXEL_SIZE + 8 * i);
    }
    const NodeArray *arrays[3] = { &g.leaf, &g.lower, &g.upper };
    for (int l = 0; l < 3; ++l) {
        s.node_count[l] = uint32_t(arrays[l]->count);
        s.node_begin[l] = arrays[l]->begin;
        s.node_end[l] = arrays[l]->count ? arrays[l]->end() : arrays[l]->begin;
    }
    s.active_voxel_count = load<uint64_t>(t + layout::TREE_OFF_VOXEL_COUNT);
    return s;
}

} // namespace

uint64_t ValidatedGrid::leaf_containing(uint64_t byte) const {
    if (m_leaf_offsets.empty())
        return (byte - m_summary.node_begin[0]) / m_leaf_size;
    return uint64_t(std::upper_bound(m_leaf_offsets.begin(), m_leaf_offsets.end(), byte) -
                    m_leaf_offsets.begin()) - 1;
}

ValidatedGrid validate_grid(const std::string &path, const void *data, uint64_t bytes,
                            IndexValues index) {
    // Read only here; the const_cast is undone by m_writable = false
    uint8_t *buf = const_cast<uint8_t *>(static_cast<const uint8_t *>(data));
    std::string name;
    const uint64_t end = check_header(path, buf, bytes, name);
    const uint32_t grid_type = load<uint32_t>(buf + layout::GRID_OFF_GRID_TYPE);
    const bool indexed = grid_type == layout::GRID_TYPE_ONINDEX;
    if (indexed) {
        if (index.count != 0 && index.values == nullptr)
            fail(path, "index grid \"" + name + "\": no values were given for its indices");
        if (index.count >= (uint64_t(1) << 32) - 1)
            fail(path, "index grid \"" + name + "\" has " + std::to_string(index.count) +
                           " values: 2^32 - 1 or more, beyond the lookups' 32-bit indices");
    } else {
        index = IndexValues{};
    }
    const ValueCodec codec(grid_type, &index);
    TreeRegions regions = check_regions(path, buf, end, codec);
    if (indexed && load<uint64_t>(buf + regions.root +
                                  layout::GRID_TYPE_CONSTANTS_ONINDEX.root_off_background) != 0)
        fail(path, "index grid \"" + name + "\": the background's value index is " +
                       std::to_string(load<uint64_t>(buf + regions.root +
                                                     layout::GRID_TYPE_CONSTANTS_ONINDEX.root_off_background)) +
                       ", not 0");

    // The grid's geometry first, for the tree view the walk reads through
    ValidatedGrid grid;
    grid.m_summary = summarize(buf, regions, name, codec);
    grid.m_leaf_size = regions.leaf.node_size;
    grid.m_leaf_offsets = regions.leaf.starts;
    grid.m_path = path;
    grid.m_data = buf;
    grid.m_bytes = bytes;
    grid.m_writable = false;
    grid.m_index = index;
    grid.m_index_grid = indexed;
    {
        const TreeView view(grid);
        TreeWalk walk(path, view, buf, regions, codec, grid.m_index);
        grid.m_values = walk.run();
        grid.m_leaf_min = std::move(walk.leaf_min);
        grid.m_leaf_max = std::move(walk.leaf_max);
    }
    return grid;
}

ValidatedGrid validate_grid(const std::string &path, void *data, uint64_t bytes,
                            IndexValues index) {
    ValidatedGrid grid = validate_grid(path, static_cast<const void *>(data), bytes, index);
    grid.m_writable = true;
    return grid;
}

} // namespace nanovdb_loader
