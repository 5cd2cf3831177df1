/*
    src/volumes/placement.h -- where nanovdbvolume's grid sits: the maths
    between the volume's local space, the grid's world space (its map), its
    index space and the majorant walk's cell space

    Spaces, for a volume whose box is the inclusive index box [min, max]
    (resolution = max - min + 1 voxels per axis):
      index   the grid's own coordinates; values sit at integers, voxel ijk's
              cell is [ijk - 1/2, ijk + 1/2]
      rel     index - min: what the sampler's lookups take (the integer min
              is added last, so grids far from the origin keep precision)
      grid world   the grid's map applied to index: map_mat * index + map_vec
      local   the volume's space (to_local of world): with
              use_grid_transform it is grid world, else the unit cube, whose
              [0, 1] spans the box's cells (rel + 1/2 = local * resolution)
      cell    the walk's: voxel ijk covers [ijk, ijk + 1)^3, relative to a
              base (a multiple of 4096 near the box)
    Each transform is composed in double and rounded once, by the caller.
    Plain maths on the loader's GridSummary and the box: no Mitsuba, no
    backend (tests/test_placement.cpp checks it).
*/

#pragma once

#include <nanovdb_loader/validation.h>

#include <drjit/matrix.h>

#include <array>
#include <cstdint>

namespace nanovdb_placement {

using Matrix4d = drjit::Matrix<double, 4>;
using Int3 = std::array<int32_t, 3>;
using Double3 = std::array<double, 3>;

/// rel (index - min) from grid world: inv_mat * (world - vec) - min
inline Matrix4d rel_from_grid_world(const nanovdb_loader::GridSummary &s, const Int3 &min) {
    Matrix4d m = drjit::identity<Matrix4d>();
    for (int r = 0; r < 3; ++r) {
        double t = 0.0;
        for (int c = 0; c < 3; ++c) {
            m(r, c) = s.map_inv[3 * r + c];
            t += s.map_inv[3 * r + c] * s.map_vec[c];
        }
        m(r, 3) = -t - (double) min[r];
    }
    return m;
}

/// Corner `corner` (bit k: the high side of axis k) of the box's cells,
/// [min - 1/2, max + 1/2], in grid world (the grid's map)
inline Double3 box_corner_in_grid_world(const nanovdb_loader::GridSummary &s, const Int3 &min,
                                        const Int3 &resolution, int corner) {
    double idx[3];
    for (int k = 0; k < 3; ++k)
        idx[k] = (corner >> k & 1) ? min[k] + resolution[k] - 0.5 : min[k] - 0.5;
    Double3 world;
    for (int r = 0; r < 3; ++r) {
        double w = s.map_vec[r];
        for (int c = 0; c < 3; ++c)
            w += s.map_mat[3 * r + c] * idx[c];
        world[r] = w;
    }
    return world;
}

/// Cell space (relative to `cell_base`) from world, given either rel from
/// world (use_grid_transform: rel_from_grid_world composed with to_local)
/// or, for the unit cube, to_local and the resolution
inline Matrix4d cell_from_rel_world(const Matrix4d &rel_from_world, const Int3 &min,
                                    const Int3 &cell_base) {
    Matrix4d m = rel_from_world;
    for (int r = 0; r < 3; ++r)
        m(r, 3) += 0.5 + double(int64_t(min[r]) - int64_t(cell_base[r]));
    return m;
}

/// Cell space from world for the unit cube: rel + 1/2 = local * resolution,
/// then relative to `cell_base`
inline Matrix4d cell_from_world_unit_cube(const Matrix4d &to_local, const Int3 &min,
                                          const Int3 &resolution, const Int3 &cell_base) {
    Matrix4d m = drjit::identity<Matrix4d>();
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 4; ++c)
            m(r, c) = to_local(r, c) * (double) resolution[r];
        m(r, 3) += double(int64_t(min[r]) - int64_t(cell_base[r]));
    }
    return m;
}

} // namespace nanovdb_placement
