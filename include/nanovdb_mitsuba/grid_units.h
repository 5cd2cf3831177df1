/*
    nanovdb_mitsuba/grid_units.h -- what a volume offers an emission
    sampler: the leaves and tiles of its grid, as places to put points and
    to find them again

    Next-event estimation toward an emissive medium (issue 35) samples
    points in proportion to what they emit, over the leaves of the emission
    volume's grid (nanovdb_drjit/emission_table.h: 4^3 blocks of 2^3 voxels
    per leaf) and its active tiles (one weight each). The medium builds the distribution from its own evaluation
    of sigma_a Le at the voxel (and tile) centres this interface names
    (src/media/emission_distribution.h); the volume (nanovdbvolume) knows
    where its leaves and tiles are in world space and which holds a point. Found
    by dynamic_cast on the medium's emission volume.
*/

#pragma once

#include <mitsuba/core/fwd.h>
#include <mitsuba/core/vector.h>

#include <tuple>

NAMESPACE_BEGIN(mitsuba)

template <typename Float, typename Spectrum> class GridUnits {
public:
    MI_IMPORT_CORE_TYPES()

    virtual ~GridUnits() = default;

    /// The grid's leaves that the functions below address (0: none, e.g.
    /// an FpN grid, whose leaves differ in size)
    virtual uint32_t unit_leaf_count() const = 0;

    /// The world point at the centre of voxel n (0..511, NanoVDB's order:
    /// n = 64 i + 8 j + k) of leaf `leaf`
    virtual Point3f leaf_voxel_point(const UInt32 &leaf, const UInt32 &n, Mask active) const = 0;

    /// A world point uniform in block `block` (emission_block(): 2^3
    /// voxels) of leaf `leaf`, for u uniform in [0, 1)^3
    virtual Point3f leaf_block_point(const UInt32 &leaf, const UInt32 &block,
                                     const Point3f &u, Mask active) const = 0;

    /// The grid's active tiles that the functions below address (units
    /// unit_leaf_count() + t; nanovdb_loader/active_tiles.h)
    virtual uint32_t unit_tile_count() const = 0;

    /// A world point uniform in tile `tile` for u uniform in [0, 1)^3 (its
    /// centre: u = 1/2), and the tile's voxels (8^3, 128^3 or 4096^3)
    virtual std::pair<Point3f, Float> tile_point(const UInt32 &tile, const Point3f &u,
                                                 Mask active) const = 0;

    /// The unit that holds a world point (a leaf l: l, and its block; a
    /// tile t: unit_leaf_count() + t, block 0), and whether one does
    virtual std::tuple<UInt32, UInt32, Mask> locate_unit(const Point3f &p, Mask active) const = 0;

    /// One voxel's world volume
    virtual ScalarFloat voxel_volume() const = 0;
};

NAMESPACE_END(mitsuba)
