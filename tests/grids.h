// Named test volumes for the nanovdb-mitsuba test suites, as NanoVDB grids.
//
// The grids themselves are nvdb_testdata's (tools/testdata/test_grids.h: built
// with OpenVDB, tiles at every NanoVDB node level and root tiles), converted
// here by NanoVDB's own nanovdb::openToNanoVDB (float values, no
// quantization). These grids are the independent inputs of
//  * the doctest suite comparing the Dr.Jit translation of PNanoVDB's read path
//    with PNanoVDB itself, read for read on query_coords(), and
//  * the pytest suite rendering each grid with the nanovdbvolume plugin and
//    with Mitsuba's dense gridvolume on write_dense_vol()'s export.
//
// Conventions: values sit at integer index coordinates; index bounding boxes
// are inclusive on the upper end ([min, max]).
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include <openvdb/openvdb.h>
#include <nanovdb/NanoVDB.h>
#include <nanovdb/util/GridHandle.h>
#include <nanovdb/util/HostBuffer.h>

#include "testdata/test_grids.h"

namespace nvdb_test {

/// Names of all cases, in a stable order; and the named case built with
/// OpenVDB (tools/testdata/test_grids.h).
using nvdb_testdata::grid_names;
using nvdb_testdata::make_vdb_grid;

/// nanovdb::openToNanoVDB(*make_vdb_grid(name, scale)): float values, no
/// quantization, NanoVDB's default statistics and checksum.
nanovdb::GridHandle<nanovdb::HostBuffer> make_nano_grid(const std::string &name,
                                                        int scale = 1);

/// Query coordinates for read-for-read comparisons, deterministic for a seed
/// (testdata/seeded.h's splitmix64, no std:: distributions, so the same on
/// every platform). Each coordinate is drawn from one of
///  (1) active values: an active voxel of a leaf, or a point inside a tile
///      (levels 1-3) that is active or holds a non-background value;
///  (2) a random point of the index bbox grown by 16 voxels;
///  (3) a point far outside: random int32 per axis, mixed with extremes
///      (INT32_MIN, INT32_MAX, their neighbours and negatives, 0, -1);
///  (4) a point on a node boundary: for a random leaf / lower / upper node or
///      root tile, per axis origin-1, origin, origin+dim-1 or origin+dim
///      (dim 8, 128, 4096, 4096), or now and then a point inside.
/// Classes that do not exist in the grid (e.g. (1) and (4) in an empty grid)
/// are left out and their share goes to the others.
std::vector<std::array<int32_t, 3>> query_coords(const nanovdb::NanoGrid<float> &grid,
                                                 size_t n, uint64_t seed);

/// Largest dense export write_dense_vol() agrees to write, in voxels (64 Mi
/// voxels = 256 MiB of float32).
constexpr uint64_t max_dense_voxels = uint64_t(1) << 26;

/// Number of voxels of the dense export of `grid` (its active index bbox, or
/// 1 for an empty grid). Compare with max_dense_voxels before exporting:
/// root_tiles_negative and far_coords are far too large.
uint64_t dense_voxel_count(const nanovdb::NanoGrid<float> &grid);

/// Dense export of the active index bbox [min, max] (inclusive) as a Mitsuba
/// .vol file (version 3, float32, one channel, little endian). Values are
/// read with NanoVDB's own accessor (grid.getAccessor().getValue(ijk)); the
/// file's bbox is the index bbox [min, max + 1] as floats, its data ordered
/// data[((z * yres + y) * xres + x)] with x, y, z offsets from min. An empty
/// grid exports a 1x1x1 volume holding the background value over [0, 1]^3.
/// Throws std::length_error when the export exceeds max_dense_voxels and
/// std::runtime_error when the file cannot be written.
/// `value`, when given, replaces the accessor's values (the decoded values of
/// a typed grid of the same topology: tests/typed_grids.h); an empty grid
/// calls it at (0, 0, 0).
void write_dense_vol(const nanovdb::NanoGrid<float> &grid, const std::string &path,
                     const std::function<float(const nanovdb::Coord &)> &value = {});

/// The same with `channels` (1 or 3) values per voxel from values(ijk, out):
/// the box is `grid`'s, the values those of a grid of the same topology
void write_dense_vol(const nanovdb::NanoGrid<float> &grid, const std::string &path,
                     int channels,
                     const std::function<void(const nanovdb::Coord &, float *)> &values);

} // namespace nvdb_test
