/*
    nanovdb_drjit/majorant_walk.h -- beyond PNanoVDB: a ray walked through the
    tree one node at a time, with the majorant of every node it crosses

    Majorant tracking samples free-flight distances against a piecewise
    constant majorant along the ray. This walk produces its pieces: it moves a
    hierarchical DDA (hdda.h, PNanoVDB's pnanovdb_hdda_*) from cell to cell,
    where a cell is whatever the tree has at that point -- a leaf (8^3), a
    tile of a lower (8^3) or upper node (128^3), a root tile or the background
    (4096^3) -- and looks up the cell's bound in the grid's majorant table
    (majorant_table.h, filled by src/loader/node_majorants.cpp):

      leaf, lower tile        its entry's byte    (max over the entry + ring,
                                                   a fraction of its brick's M)
      upper tile              max(value, R)       (R: the node's ring bound)
      root tile, background   their slots

    Empty space costs one step per node. Where crossing a whole upper node,
    lower node or brick (32^3, a level between a lower node and its leaves)
    as one cell with its bound M adds few null collisions for this ray --
    (M - m) times its width is at most `coarse_limit`, m the node's smallest
    value -- the walk does so instead of visiting its children (Cycles' rule
    of refining only where (max - min) times the cell's size is large):
    empty nodes, thin ones, and nodes of one value, however dense. The caller sets
    coarse_limit from the medium's scale and the optical depth per cell it
    accepts; 0 walks every leaf.

    Index space here is "cell space": voxel ijk covers [ijk, ijk + 1)^3, so
    a nearest lookup at q reads voxel floor(q) and a trilinear lookup reads
    the voxels within half a voxel of q. Every bound covers its cell plus a
    one-voxel ring, which is what trilinear stencils reach and leaves a
    margin of half a voxel for the rounding of positions between the walk
    and the lookups (a tricubic stencil reaches 1.5 voxels: its table is
    built with a ring of two, node_majorants(grid, 2)). Positions are
    relative to `base` (a multiple of 4096 near the grid), so that floats
    keep their precision far from the index origin; absolute coordinates
    wrap around int32 as the lookups' do.

    With `controls` (residual ratio tracking, src/integrators/tracking.h),
    each cell also gets its control and lower bound from the table
    (majorant_table.h): one more word per step inside a lower node (the
    entry's, brick's or node's), one per upper node above it. A walk that
    does not ask traces none of it.

    A step that stays in the lower node of the previous step does not go
    back to the root: the walk keeps that node (and its M and R) in its
    state. Everything is a mask and a select: one code path for scalar,
    LLVM and CUDA arrays, the traversal of the cells outside the kept lower
    node in a symbolic conditional that JIT backends skip for packets that
    do not need it.

    Tested against the lookups at 10^6 points per grid and against a walk
    done by hand on the host (tests/test_majorant_walk.cpp).
*/

#pragma once

#include <nanovdb_drjit/fast_readers.h>
#include <nanovdb_drjit/hdda.h>
#include <nanovdb_drjit/majorant_table.h>
#include <nanovdb_drjit/pnanovdb.h>
#include <nanovdb_drjit/traversal.h>
#include <nanovdb_drjit/traverse.h>

#include <drjit/idiv.h>
#include <drjit/if_stmt.h>

#include <type_traits>
#include <vector>

namespace nanovdb_drjit {

/**
 * The grid's majorant table and what the walk needs to index it, per grid.
 * JIT members are opaque per-grid values (list them in a Mitsuba plugin's
 * MI_TRAVERSE_CB), so a second grid does not recompile the kernels.
 */
template <typename UInt32> struct MajorantGrid {
    using Float = dr::float32_array_t<UInt32>;
    using Int32 = dr::int32_array_t<UInt32>;
    /// The bounds' bits: a JIT array, or a host vector on the scalar path
    using Table = std::conditional_t<dr::is_jit_v<UInt32>, UInt32, std::vector<uint32_t>>;

    Table table;
    UInt32 leaf_begin, lower_begin, upper_begin, tile_begin;
    UInt32 lower_slot, upper_slot, tile_slot;
    Float background;   ///< the background's bound (its slot, read once)
    Float clamp;        ///< lookups are clamped to this (the volume's max())
    Coord<UInt32> base; ///< cell-space positions are relative to this

    /// A volume whose lookups clamp their position to its box (gridvolume's
    /// convention) reads its edge voxels outside the box, where the tree's
    /// bounds know nothing of them: cells of the walk that do not meet the
    /// box [box_lo, box_hi] (cell space, voxels, inclusive) get `outside`
    /// (its max()) as their bound. A cell that meets the box reads only
    /// voxels of its own ringed region (the clamp keeps every position in
    /// the part of the cell inside the box), which its bound covers.
    /// Host flag: the test is traced only for such volumes.
    bool clamp_to_box = false;
    dr::Array<dr::int32_array_t<UInt32>, 3> box_lo, box_hi;
    Float outside;

    void set_clamp_box(const int32_t lo[3], const int32_t hi[3], float outside_bound) {
        clamp_to_box = true;
        // Cells of empty root space differ in bound there (inside or
        // outside the box): the walk crosses them one by one
        far_jumps = false;
        for (int k = 0; k < 3; ++k) {
            box_lo[k] = dr::opaque<dr::int32_array_t<UInt32>>(lo[k]);
            box_hi[k] = dr::opaque<dr::int32_array_t<UInt32>>(hi[k]);
        }
        outside = dr::opaque<Float>(outside_bound);
    }

    /// From the loader's table. `scale_bits` multiplies every bound (e.g. by
    /// 1 + 2^-20, to cover the few ulps by which rounded trilinear weights
    /// overshoot); `base` must be a multiple of 4096 per axis.
    static MajorantGrid make(const MajorantTableLayout &layout, const std::vector<float> &values,
                             float factor, float clamp, const int32_t base[3]) {
        MajorantGrid g;
        std::vector<uint32_t> bits(values.size());
        for (size_t i = 0; i < values.size(); ++i) {
            float v = values[i] * factor;
            std::memcpy(&bits[i], &v, 4);
        }
        // The bricks' and entries' 8-bit fractions and the controls are
        // bits, not values: kept as they are (in a lower node they follow
        // one another to its last slot)
        static_assert(LOWER_ENTRY_FRACTION_SLOT == LOWER_BRICK_FRACTION_SLOT + LOWER_BRICK_COUNT / 4 &&
                      LOWER_ENTRY_CONTROL_SLOT == LOWER_ENTRY_FRACTION_SLOT + LOWER_ENTRY_COUNT / 4 &&
                      LOWER_SLOTS == LOWER_CONTROL_SLOT + 1);
        for (uint32_t s = layout.lower_slot; s < layout.upper_slot; s += LOWER_SLOTS)
            std::memcpy(&bits[s + LOWER_BRICK_FRACTION_SLOT], &values[s + LOWER_BRICK_FRACTION_SLOT],
                        4 * (LOWER_SLOTS - LOWER_BRICK_FRACTION_SLOT));
        for (uint32_t s = layout.upper_slot; s < layout.tile_slot; s += UPPER_SLOTS)
            std::memcpy(&bits[s + UPPER_CONTROL_SLOT], &values[s + UPPER_CONTROL_SLOT], 4);
        float bg = values[layout.background_slot] * factor;
        if constexpr (dr::is_jit_v<UInt32>)
            g.table = dr::load<UInt32>(bits.data(), bits.size());
        else
            g.table = std::move(bits);
        g.leaf_begin  = dr::opaque<UInt32>(layout.leaf_begin_word);
        g.lower_begin = dr::opaque<UInt32>(layout.lower_begin_word);
        g.upper_begin = dr::opaque<UInt32>(layout.upper_begin_word);
        g.tile_begin  = dr::opaque<UInt32>(layout.tile_begin_word);
        g.lower_slot  = dr::opaque<UInt32>(layout.lower_slot);
        g.upper_slot  = dr::opaque<UInt32>(layout.upper_slot);
        g.tile_slot   = dr::opaque<UInt32>(layout.tile_slot);
        g.background  = dr::opaque<Float>(bg);
        g.clamp       = dr::opaque<Float>(clamp);
        for (int k = 0; k < 3; ++k)
            g.base[k] = dr::opaque<Int32>(base[k]);
        return g;
    }

    /// Empty root space in one step (walk_far): the first voxels of the root
    /// tiles (cell space, x y z per tile), for a grid whose active box spans
    /// more than twice as many 4096^3 cells as it has root tiles (there is
    /// empty root space to cross) and that has at most FAR_TILE_LIMIT tiles
    /// (each step through empty root space scans them). Host flag: traced
    /// only for such grids; others walk as before (measured: the scan's
    /// code alone costs up to 18 % on grids that never use it).
    static constexpr uint32_t FAR_TILE_LIMIT = 64;
    bool far_jumps = false;
    std::conditional_t<dr::is_jit_v<UInt32>, Int32, std::vector<int32_t>> far_tiles;
    UInt32 far_tile_count;

    /// From NodeMajorants::tile_origins (absolute) and the active index box
    /// [lo, hi] (absolute, inclusive)
    void set_root_tiles(const std::vector<int32_t> &origins, const int32_t base_[3],
                        const int32_t lo[3], const int32_t hi[3]) {
        const size_t n = origins.size() / 3;
        double cells = 1.0;
        for (int k = 0; k < 3; ++k)
            cells *= double((int64_t(hi[k]) >> 12) - (int64_t(lo[k]) >> 12) + 1);
        far_jumps = n <= FAR_TILE_LIMIT && cells > 2.0 * double(n) && !clamp_to_box;
        if (!far_jumps)
            return;
        std::vector<int32_t> rel(origins.size());
        for (size_t i = 0; i < rel.size(); ++i) // (int32 wrap-around, as the index space)
            rel[i] = int32_t(uint32_t(origins[i]) - uint32_t(base_[i % 3]));
        if constexpr (dr::is_jit_v<UInt32>)
            far_tiles = dr::load<Int32>(rel.data(), rel.size());
        else
            far_tiles = std::move(rel);
        far_tile_count = dr::opaque<UInt32>(uint32_t(n));
    }

    NVDB_TRAVERSE(table, leaf_begin, lower_begin, upper_begin, tile_begin, lower_slot, upper_slot,
                  tile_slot, background, clamp, base, box_lo, box_hi, outside, far_tiles,
                  far_tile_count)

    /// The table as the reads take it (a JIT array or a host pointer)
    decltype(auto) words() const {
        if constexpr (dr::is_jit_v<UInt32>)
            return (const UInt32 &) table;
        else
            return static_cast<const uint32_t *>(table.data());
    }
};

/**
 * The walk's state: the DDA, the current cell's bound, and the lower node
 * of the last step that reached one (0: none). A DRJIT_STRUCT, so it can be
 * the state of a dr::while_loop.
 */
/// majorant_table.h's brick_min and child_bound on the backend: a brick's m
/// and an entry's bound from the brick's M and their 8-bit fractions q (the
/// walk reads them so; the rebuild's mean bound too, majorant_rebuild.h)
template <typename Float, typename UInt32> Float brick_min_of(const Float &brick_M, const UInt32 &q) {
    return brick_M * (Float(q) / 255.f);
}
template <typename Float, typename UInt32> Float child_bound_of(const Float &brick_M, const UInt32 &q) {
    return dr::select(q == 0u, 0.f, dr::maximum(brick_M, 0.f) * (Float(q) * (1.f / 255.f)));
}

template <typename Float> struct MajorantWalk {
    using UInt32 = dr::uint32_array_t<Float>;
    using Int32 = dr::int32_array_t<Float>;

    Hdda<Float> hdda;
    Float majorant;                 ///< bound of the current cell (unscaled)
    UInt32 lower;                   ///< kept lower node (word address; 0: none)
    dr::Array<Int32, 3> lower_key;  ///< its 128^3 block (absolute ijk >> 7)
    Float lower_M, lower_m;         ///< its bound, and its smallest value
    UInt32 lower_slot;              ///< its first slot in the majorant table
    UInt32 brick_slot;              ///< the last brick's slot (0: none)
    Float brick_M, brick_m;         ///< ... its bound and its smallest value
    dr::mask_t<Float> far;          ///< the cell is empty root space, crossed in one step ...
    dr::Array<Int32, 3> far_voxel;  ///< ... up to this root tile's first voxel (walk_far)
    /// With controls (walk_begin's `controls`): the cell's control c (its
    /// voxels' mean) and a lower bound L of its lookups, 0 <= L <= c <=
    /// majorant (majorant_table.h); 0 and 0 without
    Float control, minorant;

    /// The start of the current cell along the ray
    Float segment_begin() const { return hdda.tmin; }

    /// The size of the current cell in voxels (8, 32, 128 or 4096)
    Int32 cell_size() const { return hdda.dim; }

    /// The end of the current cell along the ray (its bound holds on
    /// [segment_begin(), segment_end()])
    Float segment_end() const {
        return dr::minimum(dr::minimum(hdda.next.x(), hdda.next.y()),
                           dr::minimum(hdda.next.z(), hdda.tmax));
    }

    DRJIT_STRUCT(MajorantWalk, hdda, majorant, lower, lower_key, lower_M, lower_m,
                 lower_slot, brick_slot, brick_M, brick_m, far, far_voxel, control, minorant)
};

namespace detail {

template <typename UInt32, typename Table>
DRJIT_INLINE dr::float32_array_t<UInt32> read_bound(const Table &table, const UInt32 &slot,
                                                    const dr::mask_t<UInt32> &active) {
    return read_float(table, slot, active);
}

/// What a cell is: its size and bound, and the lower node it is in (if any)
template <typename UInt32> struct CellInfo {
    using Float = dr::float32_array_t<UInt32>;
    UInt32 dim;
    Float bound;
    UInt32 lower;              ///< 0 if the cell is above the lower level
    Float lower_M, lower_m;
    UInt32 lower_slot;
    dr::mask_t<UInt32> background; ///< no root tile covers the cell
    Float control, minorant;       ///< with controls, above the lower level
    DRJIT_STRUCT(CellInfo, dim, bound, lower, lower_M, lower_m, lower_slot, background, control,
                 minorant)
};

/// The bound of a tile value at `address`, whose first word the caller has
/// read: the value (Half: its low half-word, as tiles are word-aligned),
/// for Vec3f its largest channel; index grids: none beyond R
template <uint32_t GridType, typename Buffer, typename UInt32>
DRJIT_INLINE dr::float32_array_t<UInt32> tile_bound(const Buffer &buf, const UInt32 &address,
                                                    const UInt32 &first_word,
                                                    const dr::mask_t<UInt32> &active) {
    using Float = dr::float32_array_t<UInt32>;
    constexpr LeafCodec codec = grid_type_traits<GridType>::type.codec;
    if constexpr (codec == LeafCodec::Half) {
        return half_to_float(UInt32(first_word & 0xffffu));
    } else if constexpr (codec == LeafCodec::Vec3f) {
        return dr::maximum(dr::reinterpret_array<Float>(first_word),
                           dr::maximum(read_float(buf, UInt32(address + 1u), active),
                                       read_float(buf, UInt32(address + 2u), active)));
    } else if constexpr (codec == LeafCodec::OnIndex) {
        // An index, not a value: the loader keeps every upper tile's value
        // under its node's R (node_majorants.cpp), which bounds it here
        (void) first_word;
        return Float(0.f);
    } else {
        return dr::reinterpret_array<Float>(first_word);
    }
}

/// The traversal from the root down to the lower node of the cell at
/// absolute `ijk`, for lanes whose kept lower node does not hold it: the
/// cell if it is a root tile, the background, a thin upper node or an
/// upper tile; the lower node otherwise (its cell is chosen by the caller)
template <uint32_t GridType, typename Buffer, typename Root, typename UInt32>
CellInfo<UInt32> cell_above_lower(const Buffer &buf, const Root &root,
                                  const MajorantGrid<UInt32> &g, const Coord<UInt32> &ijk,
                                  const dr::float32_array_t<UInt32> &coarse_limit,
                                  const dr::mask_t<UInt32> &active, bool controls) {
    using Float = dr::float32_array_t<UInt32>;
    using Mask = dr::mask_t<UInt32>;
    constexpr const GridTypeConstants &c = constants_of<GridType>;
    const dr::divisor<uint32_t> upper_words(c.upper_size / 4), lower_words(c.lower_size / 4);

    CellInfo<UInt32> out;
    RootToUpper<UInt32> ru = root_get_upper<GridType>(buf, root, ijk, active);

    // The background, or a root tile without child: a 4096^3 cell
    UInt32 tile_slot = g.tile_slot + ((ru.tile.address - g.tile_begin) >> 3);
    static_assert(c.root_tile_size == 32, "root tile slots assume 8-word tiles");
    out.dim = UInt32(4096u);
    out.background = active & !ru.found;
    out.bound = dr::select(ru.found,
                           read_bound(g.words(), tile_slot, ru.found & !ru.has_upper),
                           g.background);

    // An upper node: one cell if thin, else its entry
    UInt32 upper_slot =
        g.upper_slot + UPPER_SLOTS * upper_words(UInt32(ru.upper.address - g.upper_begin));
    Float M_U = read_bound(g.words(), upper_slot, ru.has_upper),
          R_U = read_bound(g.words(), UInt32(upper_slot + 1u), ru.has_upper),
          m_U = read_bound(g.words(), UInt32(upper_slot + 2u), ru.has_upper);
    Mask thin_upper = ru.has_upper & ((M_U - m_U) * 4096.f <= coarse_limit);
    out.bound = dr::select(ru.has_upper, M_U, out.bound);
    Mask into_upper = ru.has_upper & !thin_upper;

    UpperToLower<UInt32> ul = upper_get_lower<GridType>(buf, ru.upper, ijk, into_upper);
    Mask upper_tile = into_upper & !ul.has_lower;
    UInt32 upper_entry = upper_get_table_address<GridType>(ru.upper, ul.n);
    Float tile_value = tile_bound<GridType>(buf, upper_entry,
                                            read_uint32(buf, upper_entry, upper_tile), upper_tile);
    out.dim = dr::select(upper_tile, UInt32(128u), out.dim);
    out.bound = dr::select(upper_tile, dr::maximum(tile_value, R_U), out.bound);
    out.control = out.minorant = Float(0.f);
    if (controls) { // root tiles and the background: 0 and 0
        auto [c_U, L_U] = control_of<16>(
            M_U, read_uint32(g.words(), UInt32(upper_slot + UPPER_CONTROL_SLOT), thin_upper));
        out.control = dr::select(thin_upper, c_U, dr::select(upper_tile, tile_value, 0.f));
        out.minorant = dr::select(thin_upper, L_U, 0.f);
    }

    LowerHandle<UInt32> lower = ul.lower;
    Mask has_lower = ul.has_lower;
    out.lower_slot = g.lower_slot +
                     LOWER_SLOTS * lower_words(UInt32(lower.address - g.lower_begin));
    out.lower = dr::select(has_lower, lower.address, UInt32(0u));
    out.lower_M = read_bound(g.words(), out.lower_slot, has_lower);
    out.lower_m = read_bound(g.words(), UInt32(out.lower_slot + 2u), has_lower);
    return out;
}

} // namespace detail

/**
 * Classifies the cell of the walk that contains the cell-space position
 * `p` (relative to g.base): sets walk.majorant (clamped to [0, g.clamp]) and
 * the kept lower node, and returns the cell's size (8, 128 or 4096).
 */
template <uint32_t GridType = GRID_TYPE_FLOAT, typename Buffer, typename Root,
          typename UInt32, typename Float>
dr::int32_array_t<Float> walk_classify(const Buffer &buf, const Root &root,
                                       const MajorantGrid<UInt32> &g,
                                       MajorantWalk<Float> &walk,
                                       const dr::Array<dr::int32_array_t<Float>, 3> &p,
                                       const Float &coarse_limit,
                                       const dr::mask_t<Float> &active, bool controls = false) {
    using Int32 = dr::int32_array_t<Float>;
    using Mask = dr::mask_t<Float>;
    using Cell = detail::CellInfo<UInt32>;
    Coord<UInt32> ijk;
    for (int k = 0; k < 3; ++k)
        ijk[k] = dr::reinterpret_array<Int32>(UInt32(dr::reinterpret_array<UInt32>(p[k]) +
                                                     dr::reinterpret_array<UInt32>(g.base[k])));
    dr::Array<Int32, 3> key = ijk >> 7;
    Mask kept = active & (walk.lower != 0u) & (key.x() == walk.lower_key.x()) &
                (key.y() == walk.lower_key.y()) & (key.z() == walk.lower_key.z());
    Mask fresh = active & !kept;

    // Lanes outside the kept lower node go down from the root
    Cell cell = dr::zeros<Cell>();
    cell.dim = UInt32(8u);
    cell.lower = walk.lower;
    cell.lower_M = walk.lower_M;
    cell.lower_m = walk.lower_m;
    cell.lower_slot = walk.lower_slot;
    // g by reference: on the scalar path its table is a host vector, which a
    // copy per step would duplicate (dr::if_stmt calls the lambda at once)
    auto from_root = [buf, root, &g, ijk, coarse_limit, controls](const Cell &kept_cell,
                                                                   const Mask &fresh_) {
        Cell out = detail::cell_above_lower<GridType>(buf, root, g, ijk, coarse_limit, fresh_,
                                                      controls);
        return dr::select(fresh_, out, kept_cell);
    };
    if constexpr (dr::is_jit_v<Float>) {
        cell = dr::if_stmt(std::make_tuple(cell, fresh), fresh, from_root,
                           [](const Cell &kept_cell, const Mask &) { return kept_cell; },
                           "nanovdb_walk_from_root");
    } else {
        if (fresh)
            cell = from_root(cell, fresh);
    }
    Mask in_lower = active & (cell.lower != 0u);
    walk.lower = dr::select(fresh & in_lower, cell.lower, walk.lower);
    walk.lower_M = dr::select(fresh & in_lower, cell.lower_M, walk.lower_M);
    walk.lower_m = dr::select(fresh & in_lower, cell.lower_m, walk.lower_m);
    walk.lower_slot = dr::select(fresh & in_lower, cell.lower_slot, walk.lower_slot);
    for (int k = 0; k < 3; ++k)
        walk.lower_key[k] = dr::select(fresh & in_lower, key[k], walk.lower_key[k]);

    // In a lower node: one cell if thin, else its brick: one cell if thin,
    // else its entry (a leaf or a tile)
    Mask thin_lower = in_lower & ((cell.lower_M - cell.lower_m) * 128.f <= coarse_limit);
    Mask into_lower = in_lower & !thin_lower;
    UInt32 u[3];
    for (int k = 0; k < 3; ++k)
        u[k] = dr::reinterpret_array<UInt32>(ijk[k]) & 127u;
    UInt32 brick = ((u[0] >> BRICK_LOG2_DIM) << 4) | ((u[1] >> BRICK_LOG2_DIM) << 2) |
                   (u[2] >> BRICK_LOG2_DIM);
    // The brick's bound and m: kept from the last step when it is the same brick
    UInt32 brick_slot = cell.lower_slot + LOWER_BRICK_M_SLOT + brick;
    Mask same_brick = into_lower & (brick_slot == walk.brick_slot),
         new_brick = into_lower & !same_brick;
    Float brick_M = dr::select(same_brick, walk.brick_M,
                               detail::read_bound(g.words(), brick_slot, new_brick));
    UInt32 fractions = read_uint32(
        g.words(), UInt32(cell.lower_slot + LOWER_BRICK_FRACTION_SLOT + (brick >> 2)), new_brick);
    Float brick_m = dr::select(
        same_brick, walk.brick_m,
        brick_min_of(brick_M, (fractions >> ((brick & 3u) << 3)) & 255u));
    walk.brick_slot = dr::select(into_lower, brick_slot, walk.brick_slot);
    walk.brick_M = dr::select(into_lower, brick_M, walk.brick_M);
    walk.brick_m = dr::select(into_lower, brick_m, walk.brick_m);
    Mask thin_brick = into_lower & ((brick_M - brick_m) * float(1u << BRICK_LOG2_DIM) <=
                                    coarse_limit);
    Mask into_brick = into_lower & !thin_brick;

    // The entry (a leaf or a tile): its bound, one byte of the table (a
    // fraction of the brick's M, majorant_table.h's child_bound), not the
    // node's child mask, its entry and the leaf's slot
    UInt32 n = lower_coord_to_offset(ijk);
    UInt32 entry_q = (read_uint32(g.words(),
                                  UInt32(cell.lower_slot + LOWER_ENTRY_FRACTION_SLOT + (n >> 2)),
                                  into_brick) >> ((n & 3u) << 3)) & 255u;
    Float entry_bound = child_bound_of(brick_M, entry_q);

    Float bound = dr::select(thin_lower, cell.lower_M, cell.bound);
    bound = dr::select(thin_brick, brick_M, bound);
    bound = dr::select(into_brick, entry_bound, bound);
    UInt32 dim = dr::select(thin_lower, UInt32(128u), cell.dim);
    dim = dr::select(thin_brick, UInt32(1u << BRICK_LOG2_DIM), dim);
    dim = dr::select(into_brick, UInt32(8u), dim);

    // Controls: in a lower node, one word of the table for the cell (the
    // entry's byte, the brick's or the node's word); above it, cell_above_lower's
    Float control = cell.control, minorant = cell.minorant;
    if (controls) {
        UInt32 slot = dr::select(into_brick, cell.lower_slot + LOWER_ENTRY_CONTROL_SLOT + (n >> 2),
                                 dr::select(thin_brick,
                                            cell.lower_slot + LOWER_BRICK_CONTROL_SLOT + (brick >> 2),
                                            cell.lower_slot + LOWER_CONTROL_SLOT));
        UInt32 word = read_uint32(g.words(), slot, thin_lower | thin_brick | into_brick);
        UInt32 byte = (word >> (dr::select(into_brick, n, brick) & 3u) * 8u) & 255u;
        auto [c8, L8] = control_of<4>(dr::select(into_brick, entry_bound, brick_M), byte);
        auto [c16, L16] = control_of<16>(cell.lower_M, word);
        control = dr::select(thin_lower, c16, dr::select(into_lower, c8, control));
        minorant = dr::select(thin_lower, L16, dr::select(into_lower, L8, minorant));
    }

    if (g.clamp_to_box) {
        Int32 d = dr::reinterpret_array<Int32>(dim), low = ~(d - 1);
        Mask outside = false;
        for (int k = 0; k < 3; ++k) {
            Int32 first = p[k] & low; // the cell's first voxel (relative to g.base)
            outside |= (first > g.box_hi[k]) | (first + (d - 1) < g.box_lo[k]);
        }
        bound = dr::select(outside, dr::maximum(bound, g.outside), bound);
        control = dr::select(outside, 0.f, control); // (ratio tracking there)
        minorant = dr::select(outside, 0.f, minorant);
    }

    // max(bound, 0) also turns the -Inf of a node without values into 0
    walk.majorant = dr::select(active, dr::minimum(dr::maximum(bound, 0.f), g.clamp),
                               walk.majorant);
    if (controls) {
        Float c = dr::clip(control, 0.f, walk.majorant);
        walk.control = dr::select(active, c, walk.control);
        walk.minorant = dr::select(active, dr::clip(minorant, 0.f, c), walk.minorant);
    }
    if (g.far_jumps)
        walk.far = dr::select(active, fresh & cell.background, walk.far);
    return dr::reinterpret_array<Int32>(dim);
}

/**
 * Beyond the DDA: a cell of empty root space (no root tile covers it) ends
 * where the ray enters the nearest root tile ahead, or at tmax, however many
 * 4096^3 cells lie between (grids whose few root tiles lie far apart: one
 * step instead of one per cell). Scans the root tiles (slab test per tile);
 * sets the segment's end (the next boundary of every axis the ray moves
 * along) and the tile where walk_advance continues. Such a segment has the
 * background's bound, which covers every cell it crosses.
 */
template <typename UInt32, typename Float>
DRJIT_NOINLINE void walk_far(const MajorantGrid<UInt32> &g, MajorantWalk<Float> &walk,
                             const dr::Array<Float, 3> &origin, const dr::mask_t<Float> &active) {
    using Int32 = dr::int32_array_t<Float>;
    using Mask = dr::mask_t<Float>;
    Hdda<Float> &h = walk.hdda;
    struct Scan {
        UInt32 i;
        Float best;
        dr::Array<Int32, 3> voxel;
        DRJIT_STRUCT(Scan, i, best, voxel)
    } s{ UInt32(0u), h.tmax, h.voxel };
    // Tiles lie outside the current cell: the ray meets the next one after
    // the cell's end (a tile it has just left ends, to rounding, at the
    // cell's start, and is not taken)
    const Float cell_end = walk.segment_end();
    dr::tie(s) = dr::while_loop(
        dr::make_tuple(s),
        [&g, active](const Scan &s_) { return Mask(active) && Mask(s_.i < g.far_tile_count); },
        [&g, &h, origin, cell_end, active](Scan &s_) {
            Float tnear = -dr::Infinity<Float>, tfar = dr::Infinity<Float>;
            dr::Array<Int32, 3> o;
            for (int a = 0; a < 3; ++a) {
                if constexpr (dr::is_jit_v<Float>)
                    o[a] = dr::gather<Int32>(g.far_tiles, UInt32(3u * s_.i + uint32_t(a)), active);
                else
                    o[a] = g.far_tiles[3 * s_.i + a];
                Float lo = Float(o[a]), hi = lo + 4096.f,
                      inv = Float(h.step[a]) * h.delta[a],
                      t0 = (lo - origin[a]) * inv, t1 = (hi - origin[a]) * inv;
                Mask still = h.step[a] == 0, inside = (origin[a] >= lo) & (origin[a] < hi);
                tnear = dr::maximum(tnear, dr::select(still, dr::select(inside, -dr::Infinity<Float>,
                                                                        dr::Infinity<Float>),
                                                      dr::minimum(t0, t1)));
                tfar = dr::minimum(tfar, dr::select(still, dr::select(inside, dr::Infinity<Float>,
                                                                      -dr::Infinity<Float>),
                                                    dr::maximum(t0, t1)));
            }
            Float enter = dr::maximum(tnear, cell_end);
            Mask nearer = active & (tfar > cell_end) & (tnear <= tfar) & (enter < s_.best);
            s_.best = dr::select(nearer, enter, s_.best);
            for (int a = 0; a < 3; ++a)
                s_.voxel[a] = dr::select(nearer, o[a], s_.voxel[a]);
            s_.i += 1u;
        },
        "nanovdb_walk_far");
    Float end = s.best; // (>= cell_end)
    for (int a = 0; a < 3; ++a) {
        h.next[a] = dr::select(active & (h.step[a] != 0), end, h.next[a]);
        walk.far_voxel[a] = dr::select(active, s.voxel[a], walk.far_voxel[a]);
    }
}

/// Beyond PNanoVDB's hdda_update: the walk's cell becomes the cell of size
/// `dim` whose first voxel is `voxel`, entered at `pos` (the ray at
/// h.tmin). No position is floored again, so a rounding error cannot move
/// the walk back across the boundary it crossed; 1 / direction comes from
/// the DDA's own step and delta, without a division.
template <typename Float>
void walk_set_cell(Hdda<Float> &h, const dr::Array<Float, 3> &pos,
                   const dr::int32_array_t<Float> &dim,
                   const dr::Array<dr::int32_array_t<Float>, 3> &voxel,
                   const dr::mask_t<Float> &active) {
    h.dim = dr::select(active, dim, h.dim);
    for (int a = 0; a < 3; ++a) {
        h.voxel[a] = dr::select(active, voxel[a], h.voxel[a]);
        Float boundary = Float(dr::select(h.step[a] > 0, voxel[a] + dim, voxel[a]));
        Float next = h.tmin + (boundary - pos[a]) * (Float(h.step[a]) * h.delta[a]);
        h.next[a] = dr::select(active & (h.step[a] != 0), next, h.next[a]);
    }
}

/// The first cell voxel `p` lies in, of size dim (dim a power of two)
template <typename Int32>
DRJIT_INLINE dr::Array<Int32, 3> cell_of(const dr::Array<Int32, 3> &p, const Int32 &dim) {
    Int32 mask = ~(dim - 1);
    return { p.x() & mask, p.y() & mask, p.z() & mask };
}

/**
 * Starts a walk along origin + t direction (cell space, relative to g.base)
 * over [tmin, tmax], at the cell that contains the point at tmin. Lanes with
 * tmin >= tmax have no segment (walk_valid is false for them).
 */
template <uint32_t GridType = GRID_TYPE_FLOAT, typename Buffer, typename Root,
          typename UInt32, typename Float>
MajorantWalk<Float> walk_begin(const Buffer &buf, const Root &root,
                               const MajorantGrid<UInt32> &g,
                               const dr::Array<Float, 3> &origin,
                               const dr::Array<Float, 3> &direction, const Float &tmin,
                               const Float &tmax, const Float &coarse_limit,
                               const dr::mask_t<Float> &active, bool controls = false) {
    using Int32 = dr::int32_array_t<Float>;
    MajorantWalk<Float> walk = dr::zeros<MajorantWalk<Float>>();
    dr::mask_t<Float> valid = active & (tmin < tmax);
    dr::Array<Int32, 3> p = hdda_pos_to_ijk(hdda_ray_start(origin, tmin, direction));
    Int32 dim = walk_classify<GridType>(buf, root, g, walk, p, coarse_limit, valid, controls);
    walk.hdda = hdda_init(origin, tmin, direction, tmax, dr::select(valid, dim, Int32(8)));
    walk.hdda.tmax = dr::select(valid, tmax, tmin);
    if (g.far_jumps)
        walk_far(g, walk, origin, valid & walk.far);
    return walk;
}

/// Whether the walk has a current segment [hdda.tmin, segment_end()]
template <typename Float> DRJIT_INLINE dr::mask_t<Float> walk_valid(const MajorantWalk<Float> &w) {
    return w.hdda.tmin < w.hdda.tmax;
}

/**
 * Moves the walk to the next cell along the ray and classifies it; returns
 * whether there is one before tmax.
 */
template <uint32_t GridType = GRID_TYPE_FLOAT, typename Buffer, typename Root,
          typename UInt32, typename Float>
dr::mask_t<Float> walk_advance(const Buffer &buf, const Root &root,
                               const MajorantGrid<UInt32> &g, MajorantWalk<Float> &walk,
                               const dr::Array<Float, 3> &origin,
                               const dr::Array<Float, 3> &direction, const Float &coarse_limit,
                               const dr::mask_t<Float> &active, bool controls = false) {
    using Int32 = dr::int32_array_t<Float>;
    using Mask = dr::mask_t<Float>;
    Hdda<Float> &h = walk.hdda;
    // Past the end: the walk stops there (tmin = tmax)
    Float end = walk.segment_end();
    Mask last = active & (end >= h.tmax);
    h.tmin = dr::select(last, h.tmax, h.tmin);
    Mask go = active & !last;
    // A cell of empty root space ends where the ray enters the root tile
    // found by walk_far: the walk continues in that tile
    Mask jumped = false;
    if (g.far_jumps)
        jumped = go & walk.far;
    hdda_step(h, go & !jumped);
    if (g.far_jumps) {
        h.tmin = dr::select(jumped, end, h.tmin);
        h.dim = dr::select(jumped, Int32(4096), h.dim);
        for (int a = 0; a < 3; ++a)
            h.voxel[a] = dr::select(jumped, walk.far_voxel[a], h.voxel[a]);
    }
    go &= h.tmin < h.tmax;
    h.tmin = dr::select(active & !go, h.tmax, h.tmin);

    // The cell entered is h.voxel at the old size; the point where the ray
    // enters it, kept inside it, picks the new cell and its size
    dr::Array<Float, 3> pos = hdda_ray_start(origin, h.tmin, direction);
    dr::Array<Int32, 3> p = hdda_pos_to_ijk(pos);
    for (int a = 0; a < 3; ++a)
        p[a] = dr::clip(p[a], h.voxel[a], h.voxel[a] + h.dim - 1);
    Int32 dim = walk_classify<GridType>(buf, root, g, walk, p, coarse_limit, go, controls);
    Mask resize = go & ((dim != h.dim) | jumped);
    walk_set_cell(h, pos, dim, cell_of(p, dim), resize);
    if (g.far_jumps)
        walk_far(g, walk, origin, go & walk.far);
    return go;
}

} // namespace nanovdb_drjit
