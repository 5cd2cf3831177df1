// What a file holds: vdb2nvdb --list, and the per-grid lines that --stats
// repeats.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include <openvdb/openvdb.h>

namespace vdb2nvdb {

/// The lines under a grid's row in --list: where it lies in world space (the
/// active voxels' cells through the transform), the transform, the values.
/// `box` is the grid's active index bbox.
std::string grid_details(const openvdb::GridBase &g, const openvdb::CoordBBox &box);

/// What nanovdb-render makes of each grid of [(name, value type)], for the
/// last column of --list: "density" (a float grid named density, any case,
/// else the first float grid), "emission (temperature)" / "emission
/// (radiance)" (the first of the other grids named emission, flame,
/// temperature, heat, in that order: temperature and heat float grids are
/// temperatures), "emission-like, unused" (the rest of those), "" otherwise.
/// The rule of python/nanovdb_mitsuba/fire.py.
std::vector<std::string> render_roles(
    const std::vector<std::pair<std::string, std::string>> &grids);

/// vdb2nvdb --list IN.vdb
int list_file(const std::string &in);

} // namespace vdb2nvdb
