// Named test volumes: OpenVDB grids converted by NanoVDB's own openToNanoVDB.
// See grids.h for what each function promises.

#include "grids.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <functional>
#include <limits>
#include <mutex>
#include <sstream>
#include <stdexcept>

#include <openvdb/tools/ChangeBackground.h>
#include <openvdb/tools/LevelSetSphere.h>
#include <openvdb/tools/LevelSetUtil.h>
#include <openvdb/tools/Prune.h>
#include <nanovdb/util/OpenToNanoVDB.h>

namespace nvdb_test {

namespace {

using openvdb::Coord;
using openvdb::FloatGrid;

// ---------------------------------------------------------------------------
// Deterministic random numbers and noise (no std:: distributions: their output
// is implementation-defined, and the grids must be the same everywhere).
// ---------------------------------------------------------------------------

uint64_t splitmix64(uint64_t x) {
    x += 0x9E3779B97F4A7C15ull;
    x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
    x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
    return x ^ (x >> 31);
}

struct Rng {
    uint64_t state;
    explicit Rng(uint64_t seed) : state(splitmix64(seed ^ 0x6E616E6F76646221ull)) {}
    uint64_t next() { return splitmix64(state++); }
    /// Uniform in [0, n); n > 0. The modulo bias (< n / 2^64) is irrelevant here.
    uint64_t below(uint64_t n) { return next() % n; }
    /// Uniform in [lo, hi] (inclusive), hi - lo < 2^63.
    int64_t range(int64_t lo, int64_t hi) { return lo + int64_t(below(uint64_t(hi - lo) + 1)); }
    /// Uniform in [0, 1).
    double uniform() { return double(next() >> 11) * 0x1.0p-53; }
};

/// Lattice hash in [0, 1).
double lattice(int64_t x, int64_t y, int64_t z, uint64_t seed) {
    uint64_t h = splitmix64(seed ^ uint64_t(x));
    h = splitmix64(h ^ uint64_t(y));
    h = splitmix64(h ^ uint64_t(z));
    return double(h >> 11) * 0x1.0p-53;
}

/// Value noise in [0, 1): trilinear interpolation of lattice hashes with
/// smoothstep weights.
double value_noise(double x, double y, double z, uint64_t seed) {
    const double fx = std::floor(x), fy = std::floor(y), fz = std::floor(z);
    const int64_t ix = int64_t(fx), iy = int64_t(fy), iz = int64_t(fz);
    auto smooth = [](double t) { return t * t * (3.0 - 2.0 * t); };
    const double u = smooth(x - fx), v = smooth(y - fy), w = smooth(z - fz);
    double c[2][2][2];
    for (int dx = 0; dx < 2; ++dx)
        for (int dy = 0; dy < 2; ++dy)
            for (int dz = 0; dz < 2; ++dz)
                c[dx][dy][dz] = lattice(ix + dx, iy + dy, iz + dz, seed);
    auto lerp = [](double a, double b, double t) { return a + (b - a) * t; };
    const double x00 = lerp(c[0][0][0], c[1][0][0], u), x10 = lerp(c[0][1][0], c[1][1][0], u),
                 x01 = lerp(c[0][0][1], c[1][0][1], u), x11 = lerp(c[0][1][1], c[1][1][1], u);
    return lerp(lerp(x00, x10, v), lerp(x01, x11, v), w);
}

/// Fractal sum of 4 octaves of value noise, normalised to [0, 1).
double fbm(double x, double y, double z, uint64_t seed) {
    double sum = 0.0, amplitude = 1.0, norm = 0.0, f = 1.0;
    for (int octave = 0; octave < 4; ++octave) {
        sum += amplitude * value_noise(x * f, y * f, z * f, seed + uint64_t(octave));
        norm += amplitude;
        amplitude *= 0.5;
        f *= 2.0;
    }
    return sum / norm;
}

// ---------------------------------------------------------------------------
// The cases. All grids: voxel size 1, identity transform (except noisy_cloud),
// grid class fog volume, grid name = case name (set by make_vdb_grid).
// ---------------------------------------------------------------------------

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
    struct Sphere { double x, y, z, r; };
    const Sphere spheres[] = { { 0, 0, 0, 16 }, { 10, 7, -4, 11 },
                               { -12, -6, 8, 10 }, { 4, -14, 12, 8 } };
    const int half = 30 * scale;
    const double inv = 1.0 / double(scale);
    auto acc = grid->getAccessor();
    for (int i = -half; i < half; ++i)
        for (int j = -half; j < half; ++j)
            for (int k = -half; k < half; ++k) {
                const double x = i * inv, y = j * inv, z = k * inv;
                double shape = -1e30; // > 0 inside a sphere, 1 at its centre
                for (const Sphere &s : spheres) {
                    const double d = std::sqrt((x - s.x) * (x - s.x) + (y - s.y) * (y - s.y) +
                                               (z - s.z) * (z - s.z));
                    shape = std::max(shape, 1.0 - d / s.r);
                }
                if (shape < -0.6) // fbm's range cannot lift it above 0
                    continue;
                const double n = fbm(x * 0.15, y * 0.15, z * 0.15, 1234);
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
    Rng rng(42);
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

// ---------------------------------------------------------------------------
// Catalogue of a NanoVDB grid's nodes and tiles, for query_coords().
// ---------------------------------------------------------------------------

using NanoRootF = nanovdb::NanoRoot<float>;
using NanoUpperF = nanovdb::NanoUpper<float>;
using NanoLowerF = nanovdb::NanoLower<float>;
using NanoLeafF = nanovdb::NanoLeaf<float>;

struct Region {
    nanovdb::Coord origin;
    int64_t dim;
};

struct ActiveLeaf {
    nanovdb::Coord origin;
    const NanoLeafF *leaf;
    uint32_t count; // active voxels
};

struct Catalogue {
    std::vector<Region> nodes[4];       // leaf, lower, upper nodes; root tiles
    std::vector<Region> valued_tiles[4]; // [1..3]: tiles active or != background
    std::vector<ActiveLeaf> active_leaves;
};

/// Origins come from the parent (root key, table offset), not from the
/// node's own bbox, which is the bbox of its active values.
template <typename NodeT>
nanovdb::Coord child_origin(const nanovdb::Coord &parent_origin, uint32_t n) {
    nanovdb::Coord local = NodeT::OffsetToLocalCoord(n);
    local <<= NodeT::ChildNodeType::TOTAL;
    return parent_origin + local;
}

template <typename NodeT, typename ChildVisitor>
void visit_internal(const NodeT &node, const nanovdb::Coord &origin, float background,
                    int level, Catalogue &cat, ChildVisitor visit_child) {
    const auto *data = node.data();
    const int64_t tile_dim = int64_t(NodeT::ChildNodeType::DIM);
    for (uint32_t n = 0; n < NodeT::SIZE; ++n) {
        const nanovdb::Coord o = child_origin<NodeT>(origin, n);
        if (data->isChild(n))
            visit_child(*data->getChild(n), o);
        else if (data->isActive(n) || data->getValue(n) != background)
            cat.valued_tiles[level].push_back({ o, tile_dim });
    }
}

Catalogue catalogue(const nanovdb::NanoGrid<float> &grid) {
    Catalogue cat;
    const auto *root = grid.tree().root().data();
    const float background = root->mBackground;
    for (uint32_t t = 0; t < root->mTableSize; ++t) {
        const auto *tile = root->tile(t);
        const nanovdb::Coord upper_origin = tile->origin();
        if (!tile->isChild()) {
            cat.nodes[3].push_back({ upper_origin, NanoUpperF::DIM });
            if (tile->state || tile->value != background)
                cat.valued_tiles[3].push_back({ upper_origin, NanoUpperF::DIM });
            continue;
        }
        cat.nodes[2].push_back({ upper_origin, NanoUpperF::DIM });
        visit_internal(*root->getChild(tile), upper_origin, background, 2, cat,
                       [&](const NanoLowerF &lower, const nanovdb::Coord &lower_origin) {
            cat.nodes[1].push_back({ lower_origin, NanoLowerF::DIM });
            visit_internal(lower, lower_origin, background, 1, cat,
                           [&](const NanoLeafF &leaf, const nanovdb::Coord &leaf_origin) {
                cat.nodes[0].push_back({ leaf_origin, NanoLeafF::DIM });
                if (uint32_t count = leaf.valueMask().countOn())
                    cat.active_leaves.push_back({ leaf_origin, &leaf, count });
            });
        });
    }
    return cat;
}

int32_t clamp_int32(int64_t v) {
    return int32_t(std::clamp<int64_t>(v, std::numeric_limits<int32_t>::min(),
                                       std::numeric_limits<int32_t>::max()));
}

/// Offset within a leaf of its `index`-th active voxel (0-based).
uint32_t nth_active(const NanoLeafF &leaf, uint32_t index) {
    const auto &mask = leaf.valueMask();
    for (uint32_t w = 0; w < mask.wordCount(); ++w) {
        uint64_t word = mask.getWord<uint64_t>(int(w));
        const uint32_t count = uint32_t(__builtin_popcountll(word));
        if (index >= count) {
            index -= count;
            continue;
        }
        for (; index > 0; --index)
            word &= word - 1; // drop the lowest set bit
        return w * 64 + uint32_t(__builtin_ctzll(word));
    }
    throw std::logic_error("nth_active: index past the active count");
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

nanovdb::GridHandle<nanovdb::HostBuffer> make_nano_grid(const std::string &name, int scale) {
    FloatGrid::Ptr grid = make_vdb_grid(name, scale);
    return nanovdb::openToNanoVDB(*grid);
}

std::vector<std::array<int32_t, 3>> query_coords(const nanovdb::NanoGrid<float> &grid,
                                                 size_t n, uint64_t seed) {
    const Catalogue cat = catalogue(grid);
    Rng rng(seed);

    std::vector<int> tile_levels, node_levels;
    for (int level = 1; level <= 3; ++level)
        if (!cat.valued_tiles[level].empty())
            tile_levels.push_back(level);
    for (int level = 0; level <= 3; ++level)
        if (!cat.nodes[level].empty())
            node_levels.push_back(level);

    // Index bbox grown by 16. An empty grid's bbox is inverted (min > max):
    // use [-16, 16]^3 around the origin instead.
    const nanovdb::CoordBBox bbox = grid.indexBBox();
    int64_t lo[3], hi[3];
    for (int a = 0; a < 3; ++a) {
        const bool empty = bbox.min()[a] > bbox.max()[a];
        lo[a] = empty ? -16 : int64_t(bbox.min()[a]) - 16;
        hi[a] = empty ? 16 : int64_t(bbox.max()[a]) + 16;
        lo[a] = clamp_int32(lo[a]);
        hi[a] = clamp_int32(hi[a]);
    }

    static const int32_t extremes[] = {
        std::numeric_limits<int32_t>::min(),     std::numeric_limits<int32_t>::min() + 1,
        std::numeric_limits<int32_t>::max(),     std::numeric_limits<int32_t>::max() - 1,
        -std::numeric_limits<int32_t>::max(),    -(std::numeric_limits<int32_t>::max() - 1),
        std::numeric_limits<int32_t>::min() + 4096, std::numeric_limits<int32_t>::max() - 4095,
        -(1 << 30),                              1 << 30,
        0,                                       -1,
    };
    const size_t extreme_count = sizeof(extremes) / sizeof(extremes[0]);

    // Shares of the four classes (1) active, (2) near the bbox, (3) far,
    // (4) node boundaries; absent classes get weight 0.
    const bool have_active = !cat.active_leaves.empty() || !tile_levels.empty();
    const double weights[4] = { have_active ? 0.3 : 0.0, 0.3, 0.1,
                                node_levels.empty() ? 0.0 : 0.3 };
    const double total = weights[0] + weights[1] + weights[2] + weights[3];

    std::vector<std::array<int32_t, 3>> out;
    out.reserve(n);
    for (size_t q = 0; q < n; ++q) {
        double pick = rng.uniform() * total;
        int cls = 0;
        while (cls < 3 && (pick >= weights[cls] || weights[cls] == 0.0)) {
            pick -= weights[cls];
            ++cls;
        }
        if (cls == 3 && node_levels.empty()) // rounding at the very end of `total`
            cls = 1;
        std::array<int32_t, 3> ijk{};
        switch (cls) {
            case 0: { // active voxel, or a point inside an active/valued tile
                const bool voxel = tile_levels.empty() ||
                                   (!cat.active_leaves.empty() && rng.below(2) == 0);
                if (voxel) {
                    const ActiveLeaf &l = cat.active_leaves[rng.below(cat.active_leaves.size())];
                    const uint32_t off = nth_active(*l.leaf, uint32_t(rng.below(l.count)));
                    ijk = { l.origin[0] + int32_t(off >> 6), l.origin[1] + int32_t((off >> 3) & 7),
                            l.origin[2] + int32_t(off & 7) };
                } else {
                    const auto &tiles = cat.valued_tiles[tile_levels[rng.below(tile_levels.size())]];
                    const Region &t = tiles[rng.below(tiles.size())];
                    for (int a = 0; a < 3; ++a)
                        ijk[a] = clamp_int32(int64_t(t.origin[a]) + int64_t(rng.below(uint64_t(t.dim))));
                }
                break;
            }
            case 1: // near the bbox
                for (int a = 0; a < 3; ++a)
                    ijk[a] = int32_t(rng.range(lo[a], hi[a]));
                break;
            case 2: // far: full int32 range with its extremes
                for (int a = 0; a < 3; ++a)
                    ijk[a] = rng.below(4) == 0 ? extremes[rng.below(extreme_count)]
                                               : int32_t(uint32_t(rng.next() >> 32));
                break;
            default: { // node boundaries: origin-1, origin, origin+dim-1, origin+dim
                const auto &nodes = cat.nodes[node_levels[rng.below(node_levels.size())]];
                const Region &r = nodes[rng.below(nodes.size())];
                for (int a = 0; a < 3; ++a) {
                    const int64_t o = r.origin[a];
                    int64_t v;
                    switch (rng.below(5)) {
                        case 0: v = o - 1; break;
                        case 1: v = o; break;
                        case 2: v = o + r.dim - 1; break;
                        case 3: v = o + r.dim; break;
                        default: v = o + int64_t(rng.below(uint64_t(r.dim))); break;
                    }
                    ijk[a] = clamp_int32(v);
                }
                break;
            }
        }
        out.push_back(ijk);
    }
    return out;
}

uint64_t dense_voxel_count(const nanovdb::NanoGrid<float> &grid) {
    const nanovdb::CoordBBox bbox = grid.indexBBox();
    unsigned __int128 count = 1; // up to (2^32)^3: 96 bits
    for (int a = 0; a < 3; ++a) {
        if (bbox.min()[a] > bbox.max()[a])
            return 1; // empty grid: one background voxel
        count *= uint64_t(int64_t(bbox.max()[a]) - int64_t(bbox.min()[a]) + 1);
    }
    const uint64_t max = std::numeric_limits<uint64_t>::max();
    return count > max ? max : uint64_t(count); // saturates; far past any limit anyway
}

void write_dense_vol(const nanovdb::NanoGrid<float> &grid, const std::string &path,
                     const std::function<float(const nanovdb::Coord &)> &value) {
    write_dense_vol(grid, path, 1, [&](const nanovdb::Coord &ijk, float *out) {
        out[0] = value ? value(ijk) : grid.getAccessor().getValue(ijk);
    });
}

void write_dense_vol(const nanovdb::NanoGrid<float> &grid, const std::string &path,
                     int channels,
                     const std::function<void(const nanovdb::Coord &, float *)> &values) {
    const uint64_t count = dense_voxel_count(grid);
    if (count > max_dense_voxels) {
        std::ostringstream msg;
        const nanovdb::CoordBBox bbox = grid.indexBBox();
        msg << "write_dense_vol(\"" << path << "\"): grid \"" << grid.gridName()
            << "\" has the index bbox [" << bbox.min()[0] << ", " << bbox.min()[1] << ", "
            << bbox.min()[2] << "] .. [" << bbox.max()[0] << ", " << bbox.max()[1] << ", "
            << bbox.max()[2] << "], " << count
            << " voxels dense; the limit is " << max_dense_voxels;
        throw std::length_error(msg.str());
    }

    const nanovdb::CoordBBox bbox = grid.indexBBox();
    const bool empty = bbox.min()[0] > bbox.max()[0] || bbox.min()[1] > bbox.max()[1] ||
                       bbox.min()[2] > bbox.max()[2];
    int32_t res[3], min[3];
    for (int a = 0; a < 3; ++a) {
        min[a] = empty ? 0 : bbox.min()[a];
        res[a] = empty ? 1 : int32_t(int64_t(bbox.max()[a]) - int64_t(bbox.min()[a]) + 1);
    }

    // Little-endian serialisation, whatever the host's byte order.
    std::vector<unsigned char> bytes;
    auto put_u32 = [&bytes](uint32_t v) {
        for (int b = 0; b < 4; ++b)
            bytes.push_back(static_cast<unsigned char>(v >> (8 * b)));
    };
    auto put_i32 = [&](int32_t v) { put_u32(static_cast<uint32_t>(v)); };
    auto put_f32 = [&](float v) {
        uint32_t bits;
        std::memcpy(&bits, &v, sizeof(bits));
        put_u32(bits);
    };

    std::ofstream file(path, std::ios::binary);
    if (!file)
        throw std::runtime_error("write_dense_vol: cannot open \"" + path + "\" for writing");
    bytes.insert(bytes.end(), { 'V', 'O', 'L', 3 });
    put_i32(1); // encoding: float32
    put_i32(res[0]);
    put_i32(res[1]);
    put_i32(res[2]);
    put_i32(channels);
    for (int a = 0; a < 3; ++a) // bbox min: the index bbox [min, max + 1]
        put_f32(float(min[a]));
    for (int a = 0; a < 3; ++a)
        put_f32(float(int64_t(min[a]) + res[a]));

    for (int32_t z = 0; z < res[2]; ++z) {
        for (int32_t y = 0; y < res[1]; ++y)
            for (int32_t x = 0; x < res[0]; ++x) {
                // an empty grid: its background, read at the origin
                const nanovdb::Coord ijk = empty ? nanovdb::Coord(0, 0, 0)
                                                 : nanovdb::Coord(min[0] + x, min[1] + y, min[2] + z);
                float v[3] = { 0.f, 0.f, 0.f };
                values(ijk, v);
                for (int c = 0; c < channels; ++c)
                    put_f32(v[c]);
            }
        file.write(reinterpret_cast<const char *>(bytes.data()), std::streamsize(bytes.size()));
        bytes.clear();
    }
    if (!file.flush())
        throw std::runtime_error("write_dense_vol: error writing \"" + path + "\"");
}

} // namespace nvdb_test
