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

#include <nanovdb_drjit/majorant_table.h>
#include <nanovdb_drjit/rebuild_plan.h>
#include <nanovdb_loader/validation.h>

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace nanovdb_loader {

/// An index box, inclusive on both ends
struct IndexBox {
    int32_t lo[3], hi[3];
};

/// The coordinates a volume's lookups read at points of its bounding box:
/// the active box (the voxel at the origin for an empty grid), grown by the
/// ring of `ring` voxels that the filter's stencils reach (0: nearest, 1:
/// trilinear, 2: tricubic; `true` is 1). An axis whose ring would leave the
/// int32 range spans all of it (stencil coordinates wrap there).
IndexBox lookup_box(const GridSummary &summary, int ring);

/// The same for a volume that spans `volume_box` (not necessarily the
/// active box): grown by `ring` voxels (filters that read the tree beyond
/// the box; 0 where they clamp to it)
IndexBox lookup_box(IndexBox volume_box, int ring);

/// The largest value (NaN skipped) a lookup at any integer coordinate of
/// `box` returns. O(nodes the box touches), plus 512 values for each leaf
/// the box cuts.
float max_in_box(const ValidatedGrid &grid, const IndexBox &box);

/// The same per channel, for Vec3f grids (one bound per channel: NaN
/// skipped, -Inf where the box holds none); a scalar grid's max_in_box()
/// three times. Decodes every value in the box (whole leaves included).
std::array<float, 3> max_in_box_per_channel(const ValidatedGrid &grid, const IndexBox &box);

/**
 * Per-node majorants for majorant tracking (nanovdb_drjit/majorant_walk.h):
 * for every region the walk can stop at, an upper bound of every value a
 * lookup returns at a point of that region, with either filter. A lookup at
 * a point of a region reads the region's voxels and, where the point lies
 * near its border (trilinear stencils, or a rounding error of half a voxel),
 * the voxels of the one-voxel ring around it; so every bound covers the
 * region grown by one voxel on every side ("ringed"). Filters that reach
 * further (tricubic: 1.5 voxels) ask for a wider ring: `ring` voxels, and
 * every "+ 1" below becomes "+ ring". All are exact maxima
 * (NaN skipped) over the sets below; `values` follows `layout`
 * (nanovdb_drjit/majorant_table.h):
 *
 *  - leaf: the max over its 8^3 voxels and their ring ([o - 1, o + 8]^3);
 *  - lower / upper node, M: the max over its whole ringed region
 *    ([o - 1, o + 128]^3, [o - 1, o + 4096]^3), that is over the ringed
 *    regions of all its entries;
 *  - lower / upper node, R: the max of the ring of those of its tiles whose
 *    ring holds a value above the tile's own (-Inf if there is none), so
 *    that max(tile value, R) bounds every tile of the node with its ring;
 *  - lower / upper node, m: the smallest value the node stores (its tiles
 *    and its leaves' voxels; no ring, NaN skipped; +Inf if none): not a
 *    bound but a measure of uniformity, M - m, for the walk's choice of
 *    crossing the node whole;
 *  - lower node brick (4^3 per node, 32^3 voxels each): the max over the
 *    ringed brick, that is over the ringed regions of its 4^3 entries;
 *  - root tile: a tile with a child: that upper node's M; without child:
 *    the max over the ringed 4096^3 block; a tile that a lookup never
 *    reaches (a later tile with the key of an earlier one): -Inf;
 *  - background: the max of the background and of the voxels of every
 *    block a root tile covers that border space no root tile covers.
 *
 * A node reached through several parents (possible in a hand-made file)
 * gets the max over all of them; a node no parent reaches keeps -Inf.
 * O(entries of the tree x 26 neighbours), plus the border voxels of those
 * neighbours whose own maximum could raise a bound.
 */
struct NodeMajorants {
    nanovdb_drjit::MajorantTableLayout layout;
    std::vector<float> values;
    /// The first voxel (x, y, z) of every valid root tile, in the root's
    /// order: where the walk can leave empty root space (MajorantGrid::
    /// set_root_tiles)
    std::vector<int32_t> tile_origins;

    uint64_t bytes() const { return uint64_t(values.size()) * sizeof(float); }
};

/// `threads`: how many threads bound the lower nodes (0: one per core, at
/// most 16, fewer for a small tree); the table is the same for any number.
NodeMajorants node_majorants(const ValidatedGrid &grid, int ring = 1, unsigned threads = 0);

/**
 * What the backend needs of an index grid's tree to rebuild its majorant
 * table from new values (nanovdb_drjit/majorant_rebuild.h): the same
 * table as node_majorants(grid, ring) computes from them. Nothing (and the
 * reason in `why`) for a grid it cannot plan: not an index grid, 2^31
 * values or more, no leaves, or a node that lookups reach not exactly once.
 */
std::optional<nanovdb_drjit::MajorantRebuildPlan>
majorant_rebuild_plan(const ValidatedGrid &grid, int ring = 1, std::string *why = nullptr);

/**
 * The mean over the voxels of `box` of the bound of the majorant walk's
 * finest cell there (leaves, tiles, 32^3 bricks and nodes of one value,
 * the background; each bound clamped to [0, clamp]): the mean density of
 * tentative collisions that tracking against the walk's bounds costs, to
 * compare with `clamp`, the one majorant of the whole volume. Near 1 x
 * clamp, the walk cannot save null collisions (a volume of one density);
 * far below, it saves most. O(entries of the nodes meeting the box).
 */
double mean_bound(const ValidatedGrid &grid, const NodeMajorants &majorants, const IndexBox &box,
                  float clamp);

} // namespace nanovdb_loader
