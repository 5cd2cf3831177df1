// src/loader/tree_view.h -- the tree of a grid as the host reads it: root
// tiles and their keys, nodes, table entries, and the coordinates they
// cover. Internal to the loader. Every host walk of the tree goes through
// it (validation, the value policy, the spectral rewrite, the reader plan,
// max_in_box, the per-node majorants and their mean), so that they all agree
// with PNanoVDB, and with each other, on which tile a coordinate reaches.
//
// Levels use PNanoVDB's codes: 0 leaf, 1 lower, 2 upper (3 root tile, 4 the
// background, for values).
#pragma once

#include <nanovdb_loader/validation.h>

#include "detail.h"

#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

namespace nanovdb_loader::detail {

// ---- Root tile keys -------------------------------------------------------------

/// PNanoVDB: pnanovdb_coord_to_key. Each coordinate's top 20 bits
/// (uint32(ijk) >> 12) in a 21-bit field, x in the highest.
inline uint64_t coord_to_key(const int32_t ijk[3]) {
    return (uint64_t(uint32_t(ijk[0]) >> 12) << 42) | (uint64_t(uint32_t(ijk[1]) >> 12) << 21) |
           uint64_t(uint32_t(ijk[2]) >> 12);
}

/// The bits of a key that coord_to_key never sets: the top bit of each
/// 21-bit field (20, 41, 62) and bit 63. PNanoVDB's search finds a tile with
/// one of them for no coordinate, but an index by block (which drops them:
/// layout::key_to_block) would: validation refuses such a tile.
constexpr uint64_t UNUSED_KEY_BITS =
    (uint64_t(1) << 20) | (uint64_t(1) << 41) | (uint64_t(1) << 62) | (uint64_t(1) << 63);

/// "bits 20 (the top bit of z's field), 63 (bit 63)": which unused bits
/// `bits` (a subset of UNUSED_KEY_BITS) holds
std::string describe_unused_key_bits(uint64_t bits);

// ---- Nodes ----------------------------------------------------------------------

/// The shape of the nodes of one level (0 leaf, 1 lower, 2 upper)
struct NodeLevel {
    uint64_t node_size;    ///< bytes of a node (not for leaves: FpN leaves differ; node())
    uint64_t mask_off;     ///< its child mask (internal nodes)
    uint64_t table_off;    ///< its first table entry (a leaf: its first value)
    uint64_t table_stride; ///< bytes per entry (internal nodes)
    uint32_t table_count;  ///< entries
    uint32_t log2dim;      ///< log2 of the entries per axis
    uint32_t log2entry;    ///< log2 of the voxels an entry spans per axis
};

/**
 * A read-only view of the tree of a grid. Made from a ValidatedGrid, every
 * child it follows is one validation checked. (Validation makes one before
 * it has checked the children, and reads with it only what follows no child
 * offset: tiles, keys, nodes, masks, entries, tile values.)
 */
class TreeView {
public:
    explicit TreeView(const ValidatedGrid &grid);

    const uint8_t *data() const { return m_buf; }
    const NodeLevel &level(int level) const { return m_level[level]; }

    // ---- Root tiles (table order) ----

    uint32_t tile_count() const { return m_tile_count; }
    /// Byte offset of root tile t
    uint64_t tile(uint32_t t) const { return m_tiles_begin + uint64_t(t) * m_tile_size; }
    uint64_t tile_key(uint32_t t) const {
        return load<uint64_t>(m_buf + tile(t) + layout::ROOT_TILE_OFF_KEY);
    }
    /// Byte offset of tile t's value
    uint64_t tile_value(uint32_t t) const { return tile(t) + m_tile_value_off; }
    /// Byte offset of tile t's upper node; 0 if it has none (a value tile)
    uint64_t tile_child(uint32_t t) const {
        const int64_t child = load<int64_t>(m_buf + tile(t) + layout::ROOT_TILE_OFF_CHILD);
        return child == 0 ? 0 : uint64_t(int64_t(m_root) + child);
    }
    /// The first voxel of the 4096^3 block a tile's key stands for
    void tile_origin(uint32_t t, int32_t origin[3]) const {
        layout::key_to_origin(tile_key(t), origin);
    }

    /// The tiles lookups reach, in table order: the first tile of each key.
    /// PNanoVDB's linear search returns the first match, so a later tile
    /// repeating a key is one that lookups never reach (nor do its nodes
    /// through it); it is left out.
    const std::vector<uint32_t> &tiles() const { return m_reached; }
    /// The tile lookups at ijk reach; false if none (the background)
    bool tile_of(const int32_t ijk[3], uint32_t &t) const {
        const uint64_t key = coord_to_key(ijk);
        if (m_reached_keys.size() <= SCAN_TILES) { // a few tiles: a scan beats a hash
            for (size_t i = 0; i < m_reached_keys.size(); ++i)
                if (m_reached_keys[i] == key) {
                    t = m_reached[i];
                    return true;
                }
            return false;
        }
        const auto it = m_tile_of_key.find(key);
        if (it == m_tile_of_key.end())
            return false;
        t = it->second;
        return true;
    }

    /// Byte offset of the background value
    uint64_t background() const { return m_background; }

    // ---- Nodes of levels 0 (leaf), 1 (lower), 2 (upper) ----

    /// Byte offset of node n of `level` (array order)
    uint64_t node(int level, uint64_t n) const {
        if (level == 0)
            return m_grid.leaf_byte(n);
        return m_s.node_begin[level] + n * m_level[level].node_size;
    }
    /// Index (array order) of the node of `level` at byte offset `byte`
    uint64_t node_index(int level, uint64_t byte) const {
        if (level == 0)
            return m_grid.leaf_containing(byte);
        return (byte - m_s.node_begin[level]) / m_level[level].node_size;
    }
    uint64_t node_count(int level) const { return m_s.node_count[level]; }

    /// Table entry e of the internal node at byte `node`: its child bit, its
    /// byte offset, and the byte offset of its child (a node of level - 1)
    bool child_bit(int level, uint64_t node, uint32_t e) const {
        const uint64_t word = node + m_level[level].mask_off + 4 * (e >> 5);
        return (load<uint32_t>(m_buf + word) >> (e & 31)) & 1u;
    }
    uint64_t entry(int level, uint64_t node, uint32_t e) const {
        return node + m_level[level].table_off + uint64_t(e) * m_level[level].table_stride;
    }
    uint64_t child(int level, uint64_t node, uint32_t e) const {
        return uint64_t(int64_t(node) + load<int64_t>(m_buf + entry(level, node, e)));
    }

    /// The first voxel of entry e of a node of `level` whose first voxel is
    /// `origin` (int32 wrap-around, as the lookups' coordinates wrap)
    void entry_origin(int level, const int32_t origin[3], uint32_t e, int32_t out[3]) const {
        const NodeLevel &l = m_level[level];
        const uint32_t mask = (1u << l.log2dim) - 1;
        const uint32_t i = e >> (2 * l.log2dim), j = (e >> l.log2dim) & mask, k = e & mask;
        out[0] = int32_t(uint32_t(origin[0]) + (i << l.log2entry));
        out[1] = int32_t(uint32_t(origin[1]) + (j << l.log2entry));
        out[2] = int32_t(uint32_t(origin[2]) + (k << l.log2entry));
    }
    /// The entry of a node of `level` that holds ijk (PNanoVDB:
    /// pnanovdb_upper_coord_to_offset, _lower_, _leaf_)
    uint32_t entry_of(int level, const int32_t ijk[3]) const {
        const NodeLevel &l = m_level[level];
        const uint32_t span = (1u << (l.log2dim + l.log2entry)) - 1;
        auto axis = [&](int a) { return (uint32_t(ijk[a]) & span) >> l.log2entry; };
        return (axis(0) << (2 * l.log2dim)) | (axis(1) << l.log2dim) | axis(2);
    }

    /// What PNanoVDB's traversal of ijk reaches at `level`: the node of that
    /// level that contains ijk or, where there is none, the value that
    /// covers ijk above it (a lower, upper or root tile, or the background)
    struct Found {
        uint64_t node = 0;  ///< byte offset of the node; 0: none
        uint64_t value = 0; ///< where there is none: byte offset of the value
    };
    Found find(int level, const int32_t ijk[3]) const {
        uint32_t t;
        if (!tile_of(ijk, t))
            return { 0, m_background };
        uint64_t node = tile_child(t);
        if (node == 0)
            return { 0, tile_value(t) };
        for (int l = 2; l > level; --l) {
            const uint32_t e = entry_of(l, ijk);
            if (!child_bit(l, node, e))
                return { 0, entry(l, node, e) };
            node = child(l, node, e);
        }
        return { node, 0 };
    }

    /// Calls f(byte offset, level, index) for every value outside the leaves
    /// that validation counts, in its order (validation.h, "Which values"):
    /// the background (level 4), the root tiles without child (3, tile
    /// index), then the upper and lower nodes' entries whose child bit is
    /// clear (2 and 1, entry index)
    template <typename F> void for_each_tile_value(F &&f) const {
        f(background(), 4, 0u);
        for (uint32_t t = 0; t < m_tile_count; ++t)
            if (tile_child(t) == 0)
                f(tile_value(t), 3, t);
        for (int l : { 2, 1 })
            for (uint64_t n = 0; n < node_count(l); ++n) {
                const uint64_t at = node(l, n);
                for (uint32_t e = 0; e < m_level[l].table_count; ++e)
                    if (!child_bit(l, at, e))
                        f(entry(l, at, e), l, e);
            }
    }

private:
    const ValidatedGrid &m_grid;
    const GridSummary &m_s;
    const uint8_t *m_buf;
    NodeLevel m_level[3];
    uint64_t m_root, m_background, m_tiles_begin, m_tile_size, m_tile_value_off;
    uint32_t m_tile_count;
    /// Up to this many reached tiles, tile_of scans their keys (the
    /// per-node majorants ask it for every neighbour: measured, a hash
    /// lookup there made loading 1.5-2x slower)
    static constexpr size_t SCAN_TILES = 32;
    std::unordered_map<uint64_t, uint32_t> m_tile_of_key; ///< key -> first tile
    std::vector<uint32_t> m_reached;
    std::vector<uint64_t> m_reached_keys; ///< their keys
};

} // namespace nanovdb_loader::detail
