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
        if (m_tile_of_key.emplace(tile_key(t), t).second) {
            m_reached.push_back(t);
            m_reached_keys.push_back(tile_key(t));
        }
}

} // namespace nanovdb_loader::detail
