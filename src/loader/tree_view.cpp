// src/loader/tree_view.cpp -- TreeView (see tree_view.h).

#include "tree_view.h"

namespace nanovdb_loader::detail {

std::string describe_unused_key_bits(uint64_t bits) {
    static const struct { uint32_t bit; const char *what; } unused[] = {
        { 20, "the top bit of z's field" }, { 41, "the top bit of y's field" },
        { 62, "the top bit of x's field" }, { 63, "bit 63" } };
    std::string list;
    size_t n = 0;
    for (const auto &u : unused) {
        if (!((bits >> u.bit) & 1u))
            continue;
        list += (n++ ? ", " : "") + std::to_string(u.bit) + " (" + u.what + ")";
    }
    return (n > 1 ? "bits " : "bit ") + list;
}

TreeView::TreeView(const ValidatedGrid &grid)
    : m_grid(grid), m_s(grid.summary()), m_buf(grid.data()) {
    const layout::GridTypeConstants &c = *layout::grid_type_constants(m_s.grid_type);
    m_level[0] = { c.leaf_size, 0, c.leaf_off_table, c.value_stride_bits / 8,
                   layout::LEAF_TABLE_COUNT, layout::LEAF_LOG2_DIM, 0 };
    m_level[1] = { c.lower_size, layout::LOWER_OFF_CHILD_MASK, c.lower_off_table, c.table_stride,
                   layout::LOWER_TABLE_COUNT, layout::LOWER_LOG2_DIM, layout::LOWER_ENTRY_LOG2 };
    m_level[2] = { c.upper_size, layout::UPPER_OFF_CHILD_MASK, c.upper_off_table, c.table_stride,
                   layout::UPPER_TABLE_COUNT, layout::UPPER_LOG2_DIM, layout::UPPER_ENTRY_LOG2 };
    m_root = uint64_t(m_s.root_word) * 4;
    m_background = m_root + c.root_off_background;
    m_tiles_begin = m_root + c.root_size;
    m_tile_size = c.root_tile_size;
    m_tile_value_off = c.root_tile_off_value;
    m_tile_count = m_s.root_tile_count;
    for (uint32_t t = 0; t < m_tile_count; ++t)
        if (m_tile_of_key.emplace(tile_key(t), t).second)
            m_reached.push_back(t);
}

bool TreeView::tile_of(const int32_t ijk[3], uint32_t &t) const {
    const auto it = m_tile_of_key.find(coord_to_key(ijk));
    if (it == m_tile_of_key.end())
        return false;
    t = it->second;
    return true;
}

uint64_t TreeView::node(int level, uint64_t n) const {
    if (level == 0)
        return m_grid.leaf_byte(n);
    return m_s.node_begin[level] + n * m_level[level].node_size;
}

uint64_t TreeView::node_index(int level, uint64_t byte) const {
    if (level == 0)
        return m_grid.leaf_containing(byte);
    return (byte - m_s.node_begin[level]) / m_level[level].node_size;
}

void TreeView::entry_origin(int level, const int32_t origin[3], uint32_t e, int32_t out[3]) const {
    const NodeLevel &l = m_level[level];
    const uint32_t mask = (1u << l.log2dim) - 1;
    const uint32_t i = e >> (2 * l.log2dim), j = (e >> l.log2dim) & mask, k = e & mask;
    out[0] = int32_t(uint32_t(origin[0]) + (i << l.log2entry));
    out[1] = int32_t(uint32_t(origin[1]) + (j << l.log2entry));
    out[2] = int32_t(uint32_t(origin[2]) + (k << l.log2entry));
}

uint32_t TreeView::entry_of(int level, const int32_t ijk[3]) const {
    const NodeLevel &l = m_level[level];
    const uint32_t span = (1u << (l.log2dim + l.log2entry)) - 1;
    auto axis = [&](int a) { return (uint32_t(ijk[a]) & span) >> l.log2entry; };
    return (axis(0) << (2 * l.log2dim)) | (axis(1) << l.log2dim) | axis(2);
}

TreeView::Found TreeView::find(int level, const int32_t ijk[3]) const {
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

} // namespace nanovdb_loader::detail
