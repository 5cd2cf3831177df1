/*
    nanovdbvolume's placement maths (src/volumes/placement.h) against the
    grid's forward map: for random affine maps (rotation, non-uniform scale
    0.1-10, translation) and boxes anywhere in int32 index space, rel_from_grid_world
    undoes map_mat * index + map_vec down to index - min; the box's corners
    are its cells' corners through the map; a point's cell coordinates are
    rel + 1/2 + min - base, from either form of local space (the grid's
    world, or the unit cube over the box's cells). Points are taken in long
    double and compared in units of the voxel, so the check also bounds the
    rounding of the double compositions far from the origin.
*/

#include "volumes/placement.h"

#include <doctest/doctest.h>

#include <cmath>
#include <random>

namespace np = nanovdb_placement;
using nanovdb_loader::GridSummary;

namespace {

/// A random affine map: R * diag(scale) (R a rotation from a random unit
/// quaternion), a translation; map_inv from the inverse of each factor
GridSummary random_map(std::mt19937_64 &rng) {
    std::normal_distribution<double> n(0.0, 1.0);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    double q[4], len = 0;
    for (double &c : q) { c = n(rng); len += c * c; }
    for (double &c : q) c /= std::sqrt(len);
    const double w = q[0], x = q[1], y = q[2], z = q[3];
    const double R[9] = { 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                          2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                          2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y) };
    double scale[3];
    // 0.1 .. 10 per axis: condition numbers up to 100, so that double's
    // rounding stays below 1e-3 voxels for indices near 2^30 (a worse-
    // conditioned map loses digits in any composition, and the plugin
    // rounds the result to float anyway)
    for (double &s : scale) s = std::pow(10.0, u(rng));
    GridSummary g;
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) {
            g.map_mat[3 * r + c] = R[3 * r + c] * scale[c];
            g.map_inv[3 * r + c] = R[3 * c + r] / scale[r];     // diag(1/s) * R^T
        }
        g.map_vec[r] = 1e3 * u(rng);
    }
    return g;
}

/// map_mat * idx + map_vec, in long double
void forward(const GridSummary &g, const long double idx[3], long double out[3]) {
    for (int r = 0; r < 3; ++r) {
        out[r] = g.map_vec[r];
        for (int c = 0; c < 3; ++c)
            out[r] += (long double) g.map_mat[3 * r + c] * idx[c];
    }
}

/// m * (p, 1), in long double
void apply(const np::Matrix4d &m, const long double p[3], long double out[3]) {
    for (int r = 0; r < 3; ++r) {
        out[r] = m(r, 3);
        for (int c = 0; c < 3; ++c)
            out[r] += (long double) m(r, c) * p[c];
    }
}

/// A box of `res` voxels from `min`, anywhere in int32 index space
void random_box(std::mt19937_64 &rng, np::Int3 &min, np::Int3 &res) {
    std::uniform_int_distribution<int32_t> lo(-(1 << 30), 1 << 30), n(1, 5000);
    for (int k = 0; k < 3; ++k) { min[k] = lo(rng); res[k] = n(rng); }
}

/// A point of the box [min, min + res) in index space
void random_index(std::mt19937_64 &rng, const np::Int3 &min, const np::Int3 &res,
                  long double idx[3]) {
    std::uniform_real_distribution<double> u(0.0, 1.0);
    for (int k = 0; k < 3; ++k)
        idx[k] = min[k] + (long double) (u(rng) * res[k]);
}

/// The walk's base near `min`: a multiple of 4096
np::Int3 walk_base(const np::Int3 &min) {
    np::Int3 base;
    for (int k = 0; k < 3; ++k)
        base[k] = int32_t(int64_t(min[k]) / 4096 * 4096);
    return base;
}

} // namespace

TEST_CASE("rel_from_grid_world undoes the grid's map down to index - min") {
    std::mt19937_64 rng(1);
    double worst = 0;
    for (int trial = 0; trial < 200; ++trial) {
        GridSummary g = random_map(rng);
        np::Int3 min, res;
        random_box(rng, min, res);
        np::Matrix4d m = np::rel_from_grid_world(g, min);
        CHECK(m(3, 0) == 0.0);
        CHECK(m(3, 3) == 1.0);
        for (int i = 0; i < 20; ++i) {
            long double idx[3], world[3], rel[3];
            random_index(rng, min, res, idx);
            forward(g, idx, world);
            apply(m, world, rel);
            for (int k = 0; k < 3; ++k)
                worst = std::max(worst, (double) std::fabs(rel[k] - (idx[k] - min[k])));
        }
    }
    // In voxels: double's rounding of coordinates near 2^30 voxels
    MESSAGE("largest error " << worst << " voxels");
    CHECK(worst < 1e-3);
}

TEST_CASE("box corners are the box's cells through the map") {
    std::mt19937_64 rng(2);
    for (int trial = 0; trial < 50; ++trial) {
        GridSummary g = random_map(rng);
        np::Int3 min, res;
        random_box(rng, min, res);
        for (int corner = 0; corner < 8; ++corner) {
            long double idx[3], world[3];
            for (int k = 0; k < 3; ++k)
                idx[k] = (corner >> k & 1) ? min[k] + res[k] - 0.5L : min[k] - 0.5L;
            forward(g, idx, world);
            np::Double3 got = np::box_corner_in_grid_world(g, min, res, corner);
            for (int k = 0; k < 3; ++k)
                CHECK(std::fabs((long double) got[k] - world[k]) <=
                      1e-12L * (1 + std::fabs(world[k])));
        }
    }
}

TEST_CASE("cell coordinates: rel + 1/2 + min - base, from the grid's world") {
    std::mt19937_64 rng(3);
    for (int trial = 0; trial < 100; ++trial) {
        GridSummary g = random_map(rng);
        np::Int3 min, res;
        random_box(rng, min, res);
        const np::Int3 base = walk_base(min);
        np::Matrix4d rel = np::rel_from_grid_world(g, min);
        np::Matrix4d cell = np::cell_from_rel_world(rel, min, base);
        long double idx[3], world[3], got[3];
        random_index(rng, min, res, idx);
        forward(g, idx, world);
        apply(cell, world, got);
        for (int k = 0; k < 3; ++k)
            CHECK(std::fabs(got[k] - (idx[k] + 0.5L - base[k])) < 1e-3L);
    }
}

TEST_CASE("cell coordinates from the unit cube: [0, 1] spans the box's cells") {
    std::mt19937_64 rng(4);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    for (int trial = 0; trial < 100; ++trial) {
        np::Int3 min, res;
        random_box(rng, min, res);
        const np::Int3 base = walk_base(min);
        // to_local: a random scale and translation of world
        np::Matrix4d to_local = drjit::identity<np::Matrix4d>();
        for (int k = 0; k < 3; ++k) {
            to_local(k, k) = 0.5 + u(rng);
            to_local(k, 3) = u(rng) - 0.5;
        }
        np::Matrix4d cell = np::cell_from_world_unit_cube(to_local, min, res, base);
        for (int i = 0; i < 10; ++i) {
            long double local[3], world[3], got[3];
            for (int k = 0; k < 3; ++k) {
                local[k] = i == 0 ? 0.0L : i == 1 ? 1.0L : (long double) u(rng);
                world[k] = (local[k] - to_local(k, 3)) / to_local(k, k);
            }
            apply(cell, world, got);
            for (int k = 0; k < 3; ++k)
                // the low face of voxel min is cell min - base; local 1 the high face of max
                CHECK(std::fabs(got[k] - (local[k] * res[k] + min[k] - base[k])) < 1e-6L);
        }
    }
}
