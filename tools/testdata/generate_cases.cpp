// The synthetic volumes of `vdb2nvdb generate`. See generate_cases.h.

#include "generate_cases.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <stdexcept>

#include <openvdb/tools/LevelSetSphere.h>
#include <openvdb/tools/Prune.h>
#include <openvdb/tree/LeafManager.h>

#include "blobs.h"
#include "noise.h"

namespace nvdb_testdata {

using openvdb::Coord;
using openvdb::CoordBBox;
using openvdb::FloatGrid;

namespace {

constexpr uint64_t kSeed = 20240917;

/// Sets every active voxel of the grid to f(ijk), leaf by leaf in parallel.
/// f returns a value <= 0 for "empty": such voxels become inactive background.
template <typename F> void fill_by_function(FloatGrid &grid, F f) {
    const float bg = grid.background();
    openvdb::tree::LeafManager<openvdb::FloatTree> leaves(grid.tree());
    leaves.foreach([&](openvdb::FloatTree::LeafNodeType &leaf, size_t) {
        for (auto it = leaf.beginValueOn(); it; ++it) {
            const float v = f(it.getCoord());
            if (v > 0.f)
                it.setValue(v);
            else {
                leaf.setValueOff(it.pos(), bg);
            }
        }
    });
}

/// A cube of n^3 active voxels, index box [0, n-1]^3, stored as leaf voxels
/// (not tiles: the case stands for a fully occupied grid), "density", fog.
FloatGrid::Ptr cube(int n, bool random) {
    auto grid = FloatGrid::create(0.f);
    grid->tree().denseFill(CoordBBox(Coord(0), Coord(n - 1)), 5.f, /*active=*/true);
    if (random)
        // uniform in [4.5, 5.5] (5.5 only through float rounding)
        fill_by_function(*grid, [](const Coord &c) {
            return float(4.5 + hash01(c.x(), c.y(), c.z(), kSeed));
        });
    grid->setName("density");
    grid->setGridClass(openvdb::GRID_FOG_VOLUME);
    return grid;
}

/// A sphere level set: radius 1, centre (0.1, -0.2, 0.3), voxel size 0.02
/// (50 voxels radius), narrow band 3 voxels each side, "ls_sphere".
FloatGrid::Ptr sphere_ls(float radius = 1.f, float voxel = 0.02f) {
    auto grid = openvdb::tools::createLevelSetSphere<FloatGrid>(
        radius, openvdb::Vec3f(0.1f, -0.2f, 0.3f), voxel, 3.f);
    grid->setName("ls_sphere");
    return grid;
}

/// A noisy cloud in the index box [-h, h)^3: a union of four blobs whose
/// edges fray and whose interior gets holes from fbm noise; density in
/// (0, 1], 0 (inactive) outside. Non-uniform voxel size and a translation, so
/// the grid transform matters. "density", fog volume.
FloatGrid::Ptr cloud(int h, double drift = 0.0) {
    auto grid = FloatGrid::create(0.f);
    grid->tree().denseFill(CoordBBox(Coord(-h), Coord(h - 1)), 1.f, true);
    static const Blob blobs[] = { { 0.0, -0.1, 0.0, 0.55 }, { 0.35, 0.2, -0.15, 0.4 },
                                  { -0.4, 0.1, 0.25, 0.35 }, { 0.1, 0.35, 0.4, 0.3 } };
    const double inv = 1.0 / double(h);
    fill_by_function(*grid, [&](const Coord &c) {
        const double x = c.x() * inv, y = c.y() * inv, z = c.z() * inv;
        const double shape = blob_shape(x, y, z, blobs);
        if (shape < -0.7)
            return 0.f;
        const double n = quintic_fbm(2.5 * x + drift, 2.5 * y, 2.5 * z, kSeed + 1);
        return float(std::clamp(2.2 * (shape + 1.4 * (n - 0.5)), 0.0, 1.0));
    });
    openvdb::tools::pruneInactive(grid->tree());
    auto xform = openvdb::math::Transform::createLinearTransform(
        openvdb::math::Mat4d(0.01, 0., 0., 0., 0., 0.01, 0., 0., 0., 0., 0.0125, 0., 0.2, 1.0, -0.3, 1.));
    grid->setTransform(xform);
    grid->setName("density");
    grid->setGridClass(openvdb::GRID_FOG_VOLUME);
    return grid;
}

/// Frame `frame` of a short animation: the noisy cloud drifting and growing.
/// Its index box is [-h, h)^3 with h = 12 + 2 frame (24^3 voxels at frame
/// 0, 4 more a side each frame), voxel size 0.02 (so the world box grows by
/// 0.08 a frame), translated by (0.05, 0.02, -0.03) a frame, its noise
/// sliding by 0.15 a frame (the shape changes, not only its size); every
/// frame has its own box and transform. "density", fog volume.
FloatGrid::Ptr drifting_cloud(int frame) {
    auto grid = cloud(12 + 2 * frame, 0.15 * frame);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(openvdb::math::Mat4d(
        0.02, 0., 0., 0., 0., 0.02, 0., 0., 0., 0., 0.02, 0., 0.05 * frame, 0.02 * frame,
        -0.03 * frame, 1.)));
    return grid;
}

/// A float grid "density" (fog volume) with no active voxels: an empty frame
FloatGrid::Ptr empty_density() {
    auto grid = FloatGrid::create(0.f);
    grid->setName("density");
    grid->setGridClass(openvdb::GRID_FOG_VOLUME);
    return grid;
}

/// The cloud with a colour: "density" as cloud(h), and "albedo" (vec3s) on
/// the same active voxels and transform, from a cool blue at the bottom to a
/// warm white at the top: an albedo grid beside a density grid.
openvdb::GridPtrVec cloud_albedo(int h) {
    FloatGrid::Ptr density = cloud(h);
    auto albedo = openvdb::Vec3SGrid::create(openvdb::Vec3s(0.f));
    albedo->setTransform(density->transform().copy());
    albedo->tree().topologyUnion(density->tree());
    albedo->tree().voxelizeActiveTiles();
    for (auto it = albedo->beginValueOn(); it; ++it) {
        const double t = std::clamp(0.5 + 0.5 * it.getCoord().y() / double(h), 0.0, 1.0);
        it.setValue(openvdb::Vec3s(float(0.55 + 0.4 * t), float(0.65 + 0.25 * t),
                                   float(0.95 - 0.25 * t)));
    }
    albedo->setName("albedo");
    return { density, albedo };
}

/// A field of small frayed cloud puffs scattered through the index box
/// [0, n)^3: 24 blobs of radius 0.04-0.09 n (deterministic positions), fbm
/// noise on their edges and inside; density in (0, 1], 0 (inactive) between
/// them. About 1-2 % of the box is occupied -- the sparsity of production
/// clouds, whose NanoVDB files are 10-15x smaller than their dense boxes.
/// Voxel size 1/n, "density", fog volume.
FloatGrid::Ptr cloudfield(int n) {
    auto grid = FloatGrid::create(0.f);
    std::vector<Blob> blobs;
    for (int b = 0; b < 24; ++b) {
        auto u = [&](int k) { return hash01(b, k, 7, kSeed + 3); };
        blobs.push_back({ 0.12 + 0.76 * u(0), 0.12 + 0.76 * u(1), 0.12 + 0.76 * u(2),
                          0.04 + 0.05 * u(3) });
    }
    // Activate each blob's bounding box only (never the whole box)
    for (const Blob &b : blobs) {
        Coord lo(int(std::floor((b.x - b.r) * n)), int(std::floor((b.y - b.r) * n)),
                 int(std::floor((b.z - b.r) * n))),
              hi(int(std::ceil((b.x + b.r) * n)), int(std::ceil((b.y + b.r) * n)),
                 int(std::ceil((b.z + b.r) * n)));
        grid->tree().denseFill(CoordBBox(lo, hi), 1.f, true);
    }
    const double inv = 1.0 / double(n);
    fill_by_function(*grid, [&](const Coord &c) {
        const double x = (c.x() + 0.5) * inv, y = (c.y() + 0.5) * inv, z = (c.z() + 0.5) * inv;
        const double shape = blob_shape(x, y, z, blobs);
        if (shape < -0.2)
            return 0.f;
        const double noise = quintic_fbm(12.0 * x, 12.0 * y, 12.0 * z, kSeed + 4);
        return float(std::clamp(2.0 * (shape + 0.8 * (noise - 0.5)), 0.0, 1.0));
    });
    openvdb::tools::pruneInactive(grid->tree());
    grid->setTransform(openvdb::math::Transform::createLinearTransform(inv));
    grid->setName("density");
    grid->setGridClass(openvdb::GRID_FOG_VOLUME);
    return grid;
}

/// Several grids in one file, in this order: "density" (float fog cloud),
/// "vel" (vec3s), "ls_sphere" (float level set, background 0.15), "flags"
/// (int32), "temperature" (float, class unknown, values 300-400).
openvdb::GridPtrVec multi() {
    openvdb::GridPtrVec grids;
    grids.push_back(cloud(24));

    auto vel = openvdb::Vec3SGrid::create(openvdb::Vec3s(0.f));
    vel->tree().fill(CoordBBox(Coord(0), Coord(9)), openvdb::Vec3s(1.f, 0.f, 0.f), true);
    vel->setName("vel");
    grids.push_back(vel);

    // Level set with a non-trivial background: 3 voxels of 0.05
    grids.push_back(sphere_ls(0.5f, 0.05f));

    auto flags = openvdb::Int32Grid::create(0);
    flags->tree().fill(CoordBBox(Coord(-4), Coord(4)), 7, true);
    flags->setName("flags");
    grids.push_back(flags);

    auto temp = FloatGrid::create(0.f);
    temp->tree().denseFill(CoordBBox(Coord(40, -8, 0), Coord(71, 23, 15)), 1.f, true);
    fill_by_function(*temp, [](const Coord &c) {
        return float(300.0 + 100.0 * hash01(c.x(), c.y(), c.z(), kSeed + 2));
    });
    temp->setName("temperature");
    grids.push_back(temp);
    return grids;
}

/// A fireball in the index box [0, n)^3, voxel size 1/n (the unit cube):
/// two fog grids with the same active voxels, "density" and "temperature"
/// (kK: times 1000 is kelvin, emissiveheterogeneous's temperature_scale).
/// A ball of radius 0.34 around (0.5, 0.47, 0.5), its surface pushed in and
/// out by fractal noise (up to +-30 %), with a soft edge of 0.06; the
/// density inside modulated by a second noise (turbulent smoke, 0.1..1).
/// The temperature falls from 2.8 (2800 K) at the centre as
/// sqrt(1 - (r / 0.85 R)^2) to 0 at 0.85 of the local radius R, varied by
/// +-15 % by a third noise: a glowing core in a dark shell (0 is below
/// every cutoff). Voxels outside the ball are inactive in both grids, so the
/// sparse grids hold the ball's leaves only.
openvdb::GridPtrVec fireball(int n) {
    const double inv = 1.0 / double(n);
    // Each noise centred and scaled to about unit spread (quintic_fbm's
    // values lie in [0, 1), around 0.5)
    auto centred = [](double v) { return (v - 0.5) * 8.0; };
    auto radius_at = [&](double x, double y, double z) {
        return 0.34 * (1.0 + 0.3 * std::tanh(centred(quintic_fbm(2 * x, 2 * y, 2 * z, kSeed + 21))
                                             / 1.5));
    };
    // a voxel's centre in the unit cube, its distance r from the ball's
    // centre and the ball's radius in its direction
    struct At { double x, y, z, r, radius; };
    auto at = [&](const Coord &c) {
        At a{ (c.x() + 0.5) * inv, (c.y() + 0.5) * inv, (c.z() + 0.5) * inv, 0.0, 0.0 };
        a.r = std::sqrt((a.x - 0.5) * (a.x - 0.5) + (a.y - 0.47) * (a.y - 0.47) +
                        (a.z - 0.5) * (a.z - 0.5));
        a.radius = radius_at(a.x, a.y, a.z);
        return a;
    };
    auto density = FloatGrid::create(0.f);
    // the largest radius, 0.34 x 1.3, and the edge: a box of 0.45 around the centre
    const Coord lo(int(std::floor(0.05 * n)), int(std::floor(0.02 * n)), int(std::floor(0.05 * n))),
                hi(int(std::ceil(0.95 * n)) - 1, int(std::ceil(0.92 * n)) - 1,
                   int(std::ceil(0.95 * n)) - 1);
    density->tree().denseFill(CoordBBox(lo, hi), 1.f, /*active=*/true);
    fill_by_function(*density, [&](const Coord &c) {
        const At a = at(c);
        const double edge = std::clamp((a.radius - a.r) / 0.06, 0.0, 1.0);
        if (edge <= 0.0)
            return 0.f;
        const double turb = std::clamp(
            0.55 + 0.3 * centred(quintic_fbm(4 * a.x, 4 * a.y, 4 * a.z, kSeed + 22)), 0.1, 1.0);
        return float(edge * turb);
    });
    openvdb::tools::pruneInactive(density->tree());
    // The temperature on the density's active voxels (0 where cold: active,
    // so that both grids have the same active box and line up by default)
    auto temperature = FloatGrid::create(0.f);
    temperature->tree().topologyUnion(density->tree());
    openvdb::tree::LeafManager<openvdb::FloatTree> leaves(temperature->tree());
    leaves.foreach([&](openvdb::FloatTree::LeafNodeType &leaf, size_t) {
        for (auto it = leaf.beginValueOn(); it; ++it) {
            const At a = at(it.getCoord());
            const double q = a.r / (0.85 * a.radius);
            double heat = std::sqrt(std::clamp(1.0 - q * q, 0.0, 1.0));
            heat *= std::clamp(
                1.0 + 0.15 * centred(quintic_fbm(3 * a.x, 3 * a.y, 3 * a.z, kSeed + 23)), 0.5, 1.5);
            it.setValue(float(2.8 * std::min(heat, 1.0)));
        }
    });
    openvdb::GridPtrVec grids;
    for (auto [grid, name] : { std::pair{ density, "density" },
                               std::pair{ temperature, "temperature" } }) {
        grid->setTransform(openvdb::math::Transform::createLinearTransform(inv));
        grid->setName(name);
        grid->setGridClass(openvdb::GRID_FOG_VOLUME);
        grids.push_back(grid);
    }
    return grids;
}

bool parse_sized(const std::string &name, const std::string &prefix, int &n) {
    if (name.rfind(prefix, 0) != 0)
        return false;
    const std::string digits = name.substr(prefix.size());
    if (digits.empty() || digits.size() > 4 ||
        !std::all_of(digits.begin(), digits.end(), [](char c) { return c >= '0' && c <= '9'; }))
        return false;
    n = std::atoi(digits.c_str());
    return n >= 1 && n <= 4096;
}


} // namespace

std::vector<std::pair<std::string, std::string>> generate_cases() {
    return {
        { "constant_300", "constant 5.0 in a 300^3 cube of active voxels (index box [0, 299]^3)" },
        { "constant_934", "the same at 934^3 (3.3 GB as voxels; not in the default tests)" },
        { "random_300", "uniform random values in [4.5, 5.5] (hash of the voxel, seeded), 300^3" },
        { "random_934", "the same at 934^3" },
        { "constant_<N>, random_<N>", "the same for any N in 1..4096" },
        { "sphere_ls", "sphere level set \"ls_sphere\", radius 1, voxel size 0.02, band 3 voxels" },
        { "cloud", "noisy cloud \"density\" (fog, 0..1), 160^3 index box, voxel size "
                   "0.01 x 0.01 x 0.0125, translated" },
        { "sphere_ls_<R>", "the sphere level set with a radius of R voxels (voxel size 1/R), "
                           "R in 1..4096; as fog, its interior becomes tiles" },
        { "cloud_<N>", "the noisy cloud in an N^3 index box" },
        { "cloud_albedo", "the cloud with a second grid, \"albedo\" (vec3s): blue at the "
                          "bottom, warm white at the top" },
        { "cloudfield_<N>", "a sparse field of 24 cloud puffs in an N^3 index box (1-2 % occupied)" },
        { "drifting_cloud_<F>", "frame F (0..1000) of a cloud that drifts and grows: index box "
                                "(24 + 4F)^3, voxel size 0.02, translated by F x (0.05, 0.02, "
                                "-0.03)" },
        { "fireball_<N>", "a fireball in an N^3 index box (voxel size 1/N): \"density\" "
                          "(turbulent smoke in a frayed ball) and \"temperature\" (kK, 2.8 at "
                          "the core, 0 in the outer shell), the same active voxels" },
        { "empty", "a float grid \"density\" (fog) with no active voxels (an empty frame)" },
        { "multi", "five grids in one file: density (fog), vel (vec3s), ls_sphere (level set, "
                   "background 0.15), flags (int32), temperature (float, class unknown)" },
    };
}

openvdb::GridPtrVec make_case(const std::string &name) {
    int n = 0;
    if (parse_sized(name, "constant_", n))
        return { cube(n, false) };
    if (parse_sized(name, "random_", n))
        return { cube(n, true) };
    if (name == "sphere_ls")
        return { sphere_ls() };
    if (parse_sized(name, "sphere_ls_", n))
        return { sphere_ls(1.f, 1.f / float(n)) };
    if (parse_sized(name, "cloudfield_", n))
        return { cloudfield(n) };
    if (parse_sized(name, "fireball_", n))
        return fireball(n);
    if (parse_sized(name, "cloud_", n))
        return { cloud(std::max(1, n / 2)) };
    if (name == "cloud")
        return { cloud(80) };
    if (name == "cloud_albedo")
        return cloud_albedo(80);
    if (name == "multi")
        return multi();
    if (name == "empty")
        return { empty_density() };
    const std::string frame = "drifting_cloud_";
    if (name.rfind(frame, 0) == 0 && name.size() > frame.size() && name.size() <= frame.size() + 4 &&
        std::all_of(name.begin() + frame.size(), name.end(),
                    [](char c) { return c >= '0' && c <= '9'; }) &&
        std::atoi(name.c_str() + frame.size()) <= 1000)
        return { drifting_cloud(std::atoi(name.c_str() + frame.size())) };
    std::string list;
    for (const auto &c : generate_cases())
        list += (list.empty() ? "" : ", ") + c.first;
    throw std::invalid_argument("unknown test volume \"" + name + "\"; the cases are: " + list);
}

} // namespace nvdb_testdata
