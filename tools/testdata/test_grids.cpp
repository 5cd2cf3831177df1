// The test suite's named volumes. See test_grids.h.

#include "test_grids.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <mutex>
#include <stdexcept>

#include <openvdb/tools/ChangeBackground.h>
#include <openvdb/tools/LevelSetSphere.h>
#include <openvdb/tools/LevelSetUtil.h>
#include <openvdb/tools/Prune.h>

#include "blobs.h"
#include "noise.h"
#include "seeded.h"

namespace nvdb_testdata {

namespace {

using openvdb::Coord;
using openvdb::FloatGrid;

FloatGrid::Ptr fog_sphere(int scale, float background) {
    // Centre off the lattice so the sphere is not symmetric about a voxel.
    auto grid = openvdb::tools::createLevelSetSphere<FloatGrid>(
        20.f * float(scale), openvdb::Vec3f(2.3f, -1.7f, 4.1f), /*voxelSize=*/1.f,
        /*halfWidth=*/3.f, /*threaded=*/false);
    // Narrow band -> fog: 0 outside, ramps to 1 inside; the interior becomes
    // active tiles of value 1 where whole nodes are inside.
    openvdb::tools::sdfToFogVolume(*grid);
    if (background != 0.f)
        openvdb::tools::changeBackground(grid->tree(), background);
    return grid;
}

FloatGrid::Ptr noisy_cloud(int scale) {
    auto grid = FloatGrid::create(0.f);
    // Index extent [-30, 30)^3 * scale: a union of spheres (in units of
    // `scale` voxels) whose edge and interior are modulated by fbm noise.
    const Blob spheres[] = { { 0, 0, 0, 16 }, { 10, 7, -4, 11 },
                             { -12, -6, 8, 10 }, { 4, -14, 12, 8 } };
    const int half = 30 * scale;
    const double inv = 1.0 / double(scale);
    auto acc = grid->getAccessor();
    for (int i = -half; i < half; ++i)
        for (int j = -half; j < half; ++j)
            for (int k = -half; k < half; ++k) {
                const double x = i * inv, y = j * inv, z = k * inv;
                const double shape = blob_shape(x, y, z, spheres); // > 0 inside a sphere
                if (shape < -0.6) // fbm's range cannot lift it above 0
                    continue;
                const double n = smooth_fbm(x * 0.15, y * 0.15, z * 0.15, 1234);
                // n is about 0.5 +- 0.3: the edge frays, the interior gets holes.
                const double density = std::clamp(3.0 * (shape + 1.6 * (n - 0.5)), 0.0, 2.0);
                if (density > 0.0)
                    acc.setValueOn(Coord(i, j, k), float(density));
            }
    openvdb::tools::pruneInactive(grid->tree());
    auto xform = openvdb::math::Transform::createLinearTransform(0.5);
    xform->postTranslate(openvdb::Vec3d(1.0, 2.0, 3.0));
    grid->setTransform(xform);
    return grid;
}

/// A 40^3 * scale box of active voxels (no prune: voxels, not tiles) placed
/// so its faces cut through leaves and it straddles the origin.
FloatGrid::Ptr cube(int scale, bool random) {
    auto grid = FloatGrid::create(0.f);
    const Coord lo(-12, -20, 5);
    const int size = 40 * scale;
    Rng rng = Rng::counter(42);
    auto acc = grid->getAccessor();
    for (int i = 0; i < size; ++i)
        for (int j = 0; j < size; ++j)
            for (int k = 0; k < size; ++k)
                acc.setValueOn(lo.offsetBy(i, j, k),
                               random ? float(4.5 + rng.uniform()) : 5.f);
    return grid;
}

/// Sets a block [lo, lo + n) of active voxels to value + 0.01 * (running index).
void set_block(FloatGrid &grid, const Coord &lo, int n, float value) {
    auto acc = grid.getAccessor();
    int index = 0;
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j)
            for (int k = 0; k < n; ++k)
                acc.setValueOn(lo.offsetBy(i, j, k), value + 0.01f * float(index++));
}

FloatGrid::Ptr lower_tiles() {
    auto grid = FloatGrid::create(0.f);
    auto &tree = grid->tree();
    // Level 1: 8^3 tiles inside lower nodes, distinct values.
    tree.addTile(1, Coord(0, 0, 0), 1.0f, true);
    tree.addTile(1, Coord(8, 0, 0), 1.25f, true);
    tree.addTile(1, Coord(0, 8, 0), 1.5f, true);
    tree.addTile(1, Coord(-8, -8, -8), 1.75f, true); // another lower, upper and root entry
    // Inactive tile with a non-background value, inside the active bbox (so a
    // dense export of the bbox sees it just as the sparse lookup does).
    tree.addTile(1, Coord(-8, 0, 8), 2.25f, false);
    // Voxels next to the tiles: levels 0 and 1 side by side.
    set_block(*grid, Coord(8, 8, 9), 4, 0.5f);
    grid->tree().setValueOn(Coord(-1, 7, 0), 0.75f);
    grid->tree().setValueOn(Coord(15, -3, 15), 0.6f);
    // Inactive background root tile far from the bbox: lookups there stop at
    // level 3 (OpenVDB keeps it; openToNanoVDB copies every root entry).
    tree.addTile(3, Coord(-3 * 4096, 8192, 0), 0.f, false);
    return grid;
}

FloatGrid::Ptr upper_tiles() {
    auto grid = FloatGrid::create(0.f);
    auto &tree = grid->tree();
    // Level 2: 128^3 tiles inside upper nodes, distinct values, in two root
    // entries. The active bbox stays 268 x 128 x 128 so the dense export
    // (17.6 MB) is still fine for a render test.
    tree.addTile(2, Coord(0, 0, 0), 2.0f, true);
    tree.addTile(2, Coord(-128, 0, 0), 3.0f, true);
    // Beside them, in the upper node of (0, 0, 0): a lower tile, an inactive
    // non-background lower tile and voxels.
    tree.addTile(1, Coord(128, 8, 8), 2.5f, true);
    tree.addTile(1, Coord(128, 16, 8), 0.5f, false);
    set_block(*grid, Coord(133, 0, 0), 7, 1.0f);
    grid->tree().setValueOn(Coord(129, 100, 120), 4.0f);
    tree.addTile(3, Coord(0, -8192, 4096), 0.f, false); // see lower_tiles()
    return grid;
}

FloatGrid::Ptr root_tiles_negative() {
    auto grid = FloatGrid::create(0.f);
    auto &tree = grid->tree();
    // Level 3: 4096^3 root tiles (the tile holding the given voxel).
    tree.addTile(3, Coord(-5000, -9000, -300), 1.5f, true);  // origin (-8192, -12288, -4096)
    tree.addTile(3, Coord(-4096, -4096, -4096), 2.5f, true); // origin (-4096, -4096, -4096)
    tree.addTile(3, Coord(4096, -8192, 0), 3.5f, true);      // origin (4096, -8192, 0)
    tree.addTile(3, Coord(-8192, 0, -8192), 7.0f, false);    // inactive, non-background value
    // An upper tile and voxel blocks in other root entries with negative
    // coordinates; the block at (-2, -9001, -2) crosses root entries in x and z.
    tree.addTile(2, Coord(-300, -5000, -9000), 4.5f, true);
    set_block(*grid, Coord(-4101, -11, -21), 3, 0.25f);
    set_block(*grid, Coord(-20001, -4, 4999), 3, 0.5f);
    set_block(*grid, Coord(-2, -9001, -2), 3, 0.75f);
    set_block(*grid, Coord(4, -6, -6), 3, 1.0f);
    return grid;
}

FloatGrid::Ptr far_coords() {
    auto grid = FloatGrid::create(0.f);
    // |ijk| from 1e6 to 1e9, positive and negative: each in its own root entry.
    const Coord voxels[] = { Coord(1000000, -1000000, 5), Coord(-999999999, 123, 999999999),
                             Coord(999999999, -999999999, -1000000) };
    float value = 1.f;
    for (const Coord &c : voxels) {
        grid->tree().setValueOn(c, value);
        value += 0.5f;
    }
    const Coord blocks[] = { Coord(-1000000, 1000000, -999999999),
                             Coord(123456789, -987654321, 555555555),
                             Coord(1000000000, -1000000000, 1000000000),
                             Coord(-1000000001, -1000000001, -1000000001) };
    for (const Coord &c : blocks) {
        set_block(*grid, c.offsetBy(-1), 3, value); // straddles a leaf boundary or two
        value += 0.5f;
    }
    return grid;
}

struct Case {
    const char *name;
    std::function<FloatGrid::Ptr(int)> make;
};

const std::vector<Case> &cases() {
    static const std::vector<Case> list = {
        { "fog_sphere", [](int s) { return fog_sphere(s, 0.f); } },
        { "noisy_cloud", noisy_cloud },
        { "constant_cube", [](int s) { return cube(s, false); } },
        { "random_cube", [](int s) { return cube(s, true); } },
        { "lower_tiles", [](int) { return lower_tiles(); } },
        { "upper_tiles", [](int) { return upper_tiles(); } },
        { "root_tiles_negative", [](int) { return root_tiles_negative(); } },
        { "far_coords", [](int) { return far_coords(); } },
        { "empty", [](int) { return FloatGrid::create(0.f); } },
        { "single_voxel",
          [](int) {
              auto grid = FloatGrid::create(0.f);
              grid->tree().setValueOn(Coord(7, -3, 12), 3.f);
              return grid;
          } },
        { "nonzero_background", [](int s) { return fog_sphere(s, 0.25f); } },
    };
    return list;
}

} // namespace

const std::vector<std::string> &grid_names() {
    static const std::vector<std::string> names = [] {
        std::vector<std::string> out;
        for (const Case &c : cases())
            out.emplace_back(c.name);
        return out;
    }();
    return names;
}

openvdb::FloatGrid::Ptr make_vdb_grid(const std::string &name, int scale) {
    static std::once_flag init;
    std::call_once(init, [] { openvdb::initialize(); });
    if (scale < 1)
        throw std::invalid_argument("make_vdb_grid: scale must be >= 1, got " +
                                    std::to_string(scale));
    for (const Case &c : cases()) {
        if (name != c.name)
            continue;
        FloatGrid::Ptr grid = c.make(scale);
        grid->setName(name);
        grid->setGridClass(openvdb::GRID_FOG_VOLUME);
        return grid;
    }
    std::string valid;
    for (const std::string &n : grid_names())
        valid += (valid.empty() ? "" : ", ") + n;
    throw std::invalid_argument("unknown test grid \"" + name + "\"; valid names: " + valid);
}

} // namespace nvdb_testdata
