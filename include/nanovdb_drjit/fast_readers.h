/*
    nanovdb_drjit/fast_readers.h -- beyond PNanoVDB: faster readers of the same tree

    Two additions that plug into the faithful translation (pnanovdb.h) through
    overloads, so that its traversal functions run unchanged on them:

      - CompactOffsets: a buffer wrapper whose child offsets are read as one
        32-bit word instead of two (read_int64_as_word_delta);
      - IndexedRootHandle: a root handle whose root_find_tile is one gather in
        a dense table instead of PNanoVDB's linear search of the root tiles.

    And `Reader`, which applies the reader policy: it holds what the loader's
    plan (src/loader/reader_policy.cpp, built once per grid on the host) chose
    for a grid and calls a traversal with the buffer and root handle that the
    plan selects. The plugin, the tests and the fuzzer all read through it.

    Both readers are tested read for read against PNanoVDB
    (tests/test_translation.cpp) on every test grid.
*/

#pragma once

#include <nanovdb_drjit/pnanovdb.h>
#include <nanovdb_drjit/traverse.h>

#include <type_traits>
#include <vector>

namespace nanovdb_drjit {

// ---------------------------------------------------------------------------
//  32-bit child offsets
// ---------------------------------------------------------------------------

/**
 * Beyond PNanoVDB: a buffer whose child offsets are all known to be
 * non-negative and below 4 GiB, so that only their low word needs reading
 * (one gather instead of two per level). The reader policy uses it for grids under
 * 4 GiB whose node arrays are stored in NanoVDB's canonical order (root, upper
 * nodes, lower nodes, leaves), where every child lies after its parent.
 */
template <typename Buffer> struct CompactOffsets {
    Buffer buf;
};

/// PNanoVDB: pnanovdb_read_uint32, on a CompactOffsets buffer
template <typename UInt32, typename Buffer>
DRJIT_INLINE UInt32 read_uint32(const CompactOffsets<Buffer> &buf, const UInt32 &address,
                                const dr::mask_t<UInt32> &active) {
    return read_uint32(buf.buf, address, active);
}

/// read_int64_as_word_delta, on a CompactOffsets buffer: the low word only
template <typename UInt32, typename Buffer>
DRJIT_INLINE std::pair<UInt32, dr::mask_t<UInt32>>
read_int64_as_word_delta(const CompactOffsets<Buffer> &buf, const UInt32 &address,
                         const dr::mask_t<UInt32> &active) {
    UInt32 lo = read_uint32(buf.buf, address, active);
    return { lo >> 2, lo != 0u };
}

// ---------------------------------------------------------------------------
//  O(1) root tile index
// ---------------------------------------------------------------------------

/**
 * Beyond PNanoVDB: a root handle with an O(1) tile index.
 *
 * `table` holds, for every 4096^3 block of the box of blocks spanned by the
 * root's tiles, the word address of that block's root tile (0: no tile, i.e.
 * background). A block is ijk >> 12 (arithmetic shift), the same grouping as
 * coord_to_key. It replaces PNanoVDB's linear search of the root table (a
 * loop with two gathers per tile) by one gather. The loader builds it on the
 * host when it is small (src/loader/reader_policy.cpp); `Table` is a JIT array
 * or, on the scalar path, a `const uint32_t *`.
 */
template <typename UInt32, typename Table> struct IndexedRootHandle {
    UInt32 address;                     ///< the root node, as in RootHandle
    Table table;                        ///< tile word addresses, x-major
    Coord<UInt32> block_min;            ///< smallest block coordinate
    Coord<UInt32> block_dims;           ///< extent of the box of blocks
};

/// PNanoVDB: pnanovdb_root_find_tile, by table lookup
template <uint32_t GridType = GRID_TYPE_FLOAT, typename UInt32, typename Table,
          typename Buffer>
DRJIT_INLINE RootTileHandle<UInt32>
root_find_tile(const Buffer & /* buf */, const IndexedRootHandle<UInt32, Table> &root,
               const Coord<UInt32> &ijk, const dr::mask_t<UInt32> &active) {
    using Mask = dr::mask_t<UInt32>;
    Coord<UInt32> rel = (ijk >> 12) - root.block_min;
    Mask inside = active;
    for (int k = 0; k < 3; ++k)
        inside &= (rel[k] >= 0) & (rel[k] < root.block_dims[k]);
    UInt32 index = dr::reinterpret_array<UInt32>(
        (rel.x() * root.block_dims.y() + rel.y()) * root.block_dims.z() + rel.z());
    return { read_uint32(root.table, index, inside) };
}

// ---------------------------------------------------------------------------
//  The reader policy, device side
// ---------------------------------------------------------------------------

/**
 * The readers a grid is traced with, as a plan chose them (see
 * src/loader/reader_policy.h): one code path per grid, never a runtime branch.
 * `UInt32` selects the backend; on the scalar path the root index table stays
 * a host vector that the handle points into.
 *
 * Its JIT members (root, root_table, block_min, block_dims) are per-grid
 * values that reach kernels as opaque variables, so a second grid does not
 * recompile them; a Mitsuba plugin lists them in MI_TRAVERSE_CB.
 */
template <typename UInt32> struct Reader {
    using Int32 = dr::int32_array_t<UInt32>;
    using Table = std::conditional_t<dr::is_jit_v<UInt32>, UInt32, std::vector<uint32_t>>;

    UInt32 root;                     ///< word address of the root node
    Table root_table;                ///< O(1) root tile index (if root_indexed)
    Coord<UInt32> block_min, block_dims; ///< ... and its box of 4096^3 blocks
    bool root_indexed = false;
    bool compact_offsets = false;

    NVDB_TRAVERSE(root, root_table, block_min, block_dims)

    /// From a plan of the loader (duck-typed: root_word, compact_offsets,
    /// root_indexed, root_table, block_min, block_dims)
    template <typename Plan> static Reader from_plan(const Plan &plan) {
        Reader r;
        r.root = dr::opaque<UInt32>(plan.root_word);
        r.compact_offsets = plan.compact_offsets;
        r.root_indexed = plan.root_indexed;
        for (int k = 0; k < 3; ++k) {
            r.block_min[k] = dr::opaque<Int32>(plan.block_min[k]);
            r.block_dims[k] = dr::opaque<Int32>(plan.block_dims[k]);
        }
        if (plan.root_indexed) {
            // An empty table is still one entry (no tile): a gather needs an array
            std::vector<uint32_t> table = plan.root_table;
            if (table.empty())
                table.push_back(0u);
            if constexpr (dr::is_jit_v<UInt32>)
                r.root_table = dr::load<UInt32>(table.data(), table.size());
            else
                r.root_table = std::move(table);
        }
        return r;
    }

    /// Calls fn(buffer, root_handle) with the readers of the plan. `buf` is
    /// the grid: a JIT array of UInt32, or a `const uint32_t *` on scalars.
    template <typename Buffer, typename Fn>
    decltype(auto) apply(const Buffer &buf, Fn &&fn) const {
        auto with_root = [&](const auto &b) -> decltype(auto) {
            if (root_indexed) {
                if constexpr (dr::is_jit_v<UInt32>)
                    return fn(b, IndexedRootHandle<UInt32, UInt32>{
                                     root, root_table, block_min, block_dims });
                else
                    return fn(b, IndexedRootHandle<UInt32, const uint32_t *>{
                                     root, root_table.data(), block_min, block_dims });
            }
            return fn(b, RootHandle<UInt32>{ root });
        };
        if (compact_offsets)
            return with_root(CompactOffsets<Buffer>{ buf });
        return with_root(buf);
    }
};

} // namespace nanovdb_drjit
