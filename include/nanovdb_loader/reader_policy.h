// nanovdb_loader/reader_policy.h -- which readers the traversal uses for a grid.
//
// Decided once per grid, on the host, from the validated bytes: the plugin,
// the tests and the fuzzer all take their readers from plan_readers(), and the
// device side (nanovdb_drjit::Reader in fast_readers.h) applies the plan.
//  * compact_offsets: every child offset is non-negative and below 4 GiB, so
//    one 32-bit word of each suffices (CompactOffsets);
//  * root_indexed: the O(1) root tile index (IndexedRootHandle) replaces
//    PNanoVDB's linear search of the root tiles where its table is small.
#pragma once

#include <nanovdb_loader/validation.h>

#include <cstdint>
#include <vector>

namespace nanovdb_loader {

struct ReaderPlan {
    uint32_t root_word = 0;           ///< byte offset of the root node / 4
    bool compact_offsets = false;
    bool root_indexed = false;
    /// The O(1) root index (where root_indexed): for every 4096^3 block of
    /// the box of blocks spanned by the root tiles, x-major, the word address
    /// of its root tile (0: none, i.e. background)
    std::vector<uint32_t> root_table;
    int32_t block_min[3] = { 0, 0, 0 };
    int32_t block_dims[3] = { 0, 0, 0 };

    /// The same grid read with PNanoVDB's own algorithm (no fast reader)
    ReaderPlan faithful() const {
        ReaderPlan p;
        p.root_word = root_word;
        return p;
    }
};

/// The root index is built where it takes at most this many entries of 4
/// bytes: about 0.4 % of the grid's bytes (grid bytes / 1024, at least 64)
uint64_t max_root_index_entries(uint64_t grid_bytes);

/// The plan for a validated grid
ReaderPlan plan_readers(const ValidatedGrid &grid);

/// True if the child offsets of the grid allow CompactOffsets: the buffer is
/// smaller than 4 GiB and the node arrays are laid out in NanoVDB's canonical
/// order (root, then upper nodes, lower nodes and leaves, each array after
/// the previous one), so every child lies after its parent. NanoVDB's writers
/// always produce this layout.
bool has_compact_offsets(const ValidatedGrid &grid);

/// Builds the O(1) root index into `plan`, or returns false if the box of
/// 4096^3 blocks spanned by the root tiles needs more than `max_entries`
bool build_root_index(const ValidatedGrid &grid, uint64_t max_entries, ReaderPlan &plan);

} // namespace nanovdb_loader
