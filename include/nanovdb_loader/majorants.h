// nanovdb_loader/majorants.h -- upper bounds of what lookups can return.
//
// A medium samples free-flight distances against a majorant, which must bound
// every value a lookup returns where the medium looks, and is fast only when
// it is tight. The grid's own maximum (ValueStats::max) counts values no
// lookup inside the volume reaches: a fog volume converted from a level set
// may keep the level set's background (e.g. 3.0) in its root, three times its
// densest voxel. max_in_box() is the largest value lookups at the integer
// coordinates of a box can return, from the tree itself: leaf voxels
// (through the per-leaf maxima validation recorded, voxel by voxel only for
// leaves the box cuts), internal and root tiles, and the background where
// the box reaches space no root tile covers.
#pragma once

#include <nanovdb_loader/validation.h>

#include <cstdint>

namespace nanovdb_loader {

/// An index box, inclusive on both ends
struct IndexBox {
    int32_t lo[3], hi[3];
};

/// The coordinates a volume's lookups read at points of its bounding box:
/// the active box (the voxel at the origin for an empty grid), for trilinear
/// grown by the one-voxel ring that stencils reach. An axis whose ring would
/// leave the int32 range spans all of it (stencil coordinates wrap there).
IndexBox lookup_box(const GridSummary &summary, bool trilinear);

/// The largest value (NaN skipped) a lookup at any integer coordinate of
/// `box` returns. O(nodes the box touches), plus 512 values for each leaf
/// the box cuts.
float max_in_box(const ValidatedGrid &grid, const IndexBox &box);

} // namespace nanovdb_loader
