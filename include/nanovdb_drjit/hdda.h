/*
    nanovdb_drjit/hdda.h -- Dr.Jit translation of PNanoVDB's hierarchical DDA

    PNanoVDB (nanovdb/PNanoVDB.h, NanoVDB 32.4, Copyright Contributors to the
    OpenVDB Project, SPDX-License-Identifier: MPL-2.0) walks a ray through
    index space one cell at a time, where the cell size `dim` (1, 8, 128,
    4096) can change at every step: pnanovdb_hdda_init, _update (a new cell
    size at the current t), _step (to the next cell boundary) and _ray_clip
    (a ray against an index bounding box). This header re-implements them in
    Dr.Jit, function for function (no PNanoVDB code), for every backend:
    `Float` is `float` (scalar), or an LLVM/CUDA array, and every lane can
    have its own cell size. Branches on lane data are `dr::select`s in the
    order of PNanoVDB's `if`s; each function's arithmetic is PNanoVDB's,
    operation for operation (a multiply and an add stay two roundings: no
    fused multiply-add), so the walk is the same, step for step. Built with
    PNANOVDB_ENFORCE_FORWARD_STEPPING, as PNanoVDB defines it by default.

    What a walk does with each cell (a majorant, a lookup) is not here: see
    the tracking code that uses it. Tested step for step against PNanoVDB's C
    code on random rays (tests/test_hdda.cpp).
*/

#pragma once

#include <drjit/array.h>
#include <drjit/array_traverse.h>

namespace nanovdb_drjit {

namespace dr = drjit;

/// PNanoVDB: PNANOVDB_HDDA_FLOAT_MAX
static constexpr float HDDA_FLOAT_MAX = 1e38f;

/// PNanoVDB: pnanovdb_hdda_t
template <typename Float> struct Hdda {
    using Int32 = dr::int32_array_t<Float>;
    using Vector3 = dr::Array<Float, 3>;
    using Coord3 = dr::Array<Int32, 3>;

    Int32 dim;       ///< the current cell size (a power of two)
    Float tmin;      ///< the ray parameter at the entry of the current cell
    Float tmax;      ///< the end of the walk
    Coord3 voxel;    ///< the current cell's first voxel (a multiple of dim)
    Coord3 step;     ///< -1, 0 or +1 per axis
    Vector3 delta;   ///< |1 / direction| per axis
    Vector3 next;    ///< the ray parameter of the next cell boundary per axis

    DRJIT_STRUCT(Hdda, dim, tmin, tmax, voxel, step, delta, next)
};

/// a * b + c in two roundings, as PNanoVDB's C code computes it (no FMA
/// contraction: tests build with -ffp-contract=off, and Dr.Jit's JIT emits a
/// separate multiply and add)
template <typename Float>
DRJIT_INLINE Float hdda_mul_add(const Float &a, const Float &b, const Float &c) {
    Float product = a * b;
    return product + c;
}

/// PNanoVDB: pnanovdb_hdda_pos_to_ijk
template <typename Float>
DRJIT_INLINE dr::Array<dr::int32_array_t<Float>, 3>
hdda_pos_to_ijk(const dr::Array<Float, 3> &pos) {
    using Int32 = dr::int32_array_t<Float>;
    return { Int32(dr::floor(pos.x())), Int32(dr::floor(pos.y())), Int32(dr::floor(pos.z())) };
}

/// PNanoVDB: pnanovdb_hdda_pos_to_voxel (the first voxel of the dim^3 cell)
template <typename Float>
DRJIT_INLINE dr::Array<dr::int32_array_t<Float>, 3>
hdda_pos_to_voxel(const dr::Array<Float, 3> &pos, const dr::int32_array_t<Float> &dim) {
    using Int32 = dr::int32_array_t<Float>;
    Int32 mask = ~(dim - 1);
    return { Int32(dr::floor(pos.x())) & mask, Int32(dr::floor(pos.y())) & mask,
             Int32(dr::floor(pos.z())) & mask };
}

/// PNanoVDB: pnanovdb_hdda_ray_start (direction * tmin + origin)
template <typename Float>
DRJIT_INLINE dr::Array<Float, 3> hdda_ray_start(const dr::Array<Float, 3> &origin,
                                                const Float &tmin,
                                                const dr::Array<Float, 3> &direction) {
    return { hdda_mul_add(direction.x(), tmin, origin.x()),
             hdda_mul_add(direction.y(), tmin, origin.y()),
             hdda_mul_add(direction.z(), tmin, origin.z()) };
}

/// PNanoVDB: pnanovdb_hdda_init
template <typename Float>
Hdda<Float> hdda_init(const dr::Array<Float, 3> &origin, const Float &tmin,
                      const dr::Array<Float, 3> &direction, const Float &tmax,
                      const dr::int32_array_t<Float> &dim) {
    using Int32 = dr::int32_array_t<Float>;
    using Mask = dr::mask_t<Float>;
    Hdda<Float> h;
    h.dim = dim;
    h.tmin = tmin;
    h.tmax = tmax;
    dr::Array<Float, 3> pos = hdda_ray_start(origin, tmin, direction);
    dr::Array<Float, 3> dir_inv = Float(1.f) / direction;
    h.voxel = hdda_pos_to_voxel(pos, dim);
    for (int a = 0; a < 3; ++a) {
        Mask zero = direction[a] == 0.f, forward = dir_inv[a] > 0.f;
        // (voxel + dim - pos) * dir_inv: the integers add first, as in C
        Float next_forward  = h.tmin + (Float(h.voxel[a] + dim) - pos[a]) * dir_inv[a],
              next_backward = h.tmin + (Float(h.voxel[a]) - pos[a]) * dir_inv[a];
        h.next[a] = dr::select(zero, Float(HDDA_FLOAT_MAX),
                               dr::select(forward, next_forward, next_backward));
        h.step[a] = dr::select(zero, Int32(0), dr::select(forward, Int32(1), Int32(-1)));
        h.delta[a] = dr::select(zero, Float(0.f), dr::select(forward, dir_inv[a], -dir_inv[a]));
    }
    return h;
}

/// PNanoVDB: pnanovdb_hdda_update. A new cell size at the current tmin;
/// returns the lanes whose size changed (the others are left as they are).
template <typename Float>
dr::mask_t<Float> hdda_update(Hdda<Float> &h, const dr::Array<Float, 3> &origin,
                              const dr::Array<Float, 3> &direction,
                              const dr::int32_array_t<Float> &dim,
                              const dr::mask_t<Float> &active = true) {
    using Mask = dr::mask_t<Float>;
    Mask changed = active & (h.dim != dim);
    h.dim = dr::select(changed, dim, h.dim);
    dr::Array<Float, 3> pos = hdda_ray_start(origin, h.tmin, direction);
    dr::Array<Float, 3> dir_inv = Float(1.f) / direction;
    h.voxel = dr::select(changed, hdda_pos_to_voxel(pos, dim), h.voxel);
    for (int a = 0; a < 3; ++a) {
        Float next = h.tmin + (Float(h.voxel[a]) - pos[a]) * dir_inv[a];
        next = dr::select(h.step[a] > 0, next + Float(dim) * dir_inv[a], next);
        h.next[a] = dr::select(changed & (h.step[a] != 0), next, h.next[a]);
    }
    return changed;
}

/// PNanoVDB: pnanovdb_hdda_step. To the next cell along the ray; returns
/// whether it starts before tmax.
template <typename Float>
dr::mask_t<Float> hdda_step(Hdda<Float> &h, const dr::mask_t<Float> &active = true) {
    using Mask = dr::mask_t<Float>;
    Mask along_x = Mask(h.next.x() < h.next.y()) && Mask(h.next.x() < h.next.z()),
         along_y = (!along_x) && Mask(h.next.y() < h.next.z()),
         along_z = (!along_x) && (!along_y);
    Mask along[3] = { Mask(along_x && active), Mask(along_y && active), Mask(along_z && active) };
    for (int a = 0; a < 3; ++a) {
        // PNANOVDB_ENFORCE_FORWARD_STEPPING: a boundary at or behind tmin
        // (round-off) is pushed just past it
        Float pushed = h.next[a] + ((h.tmin - 0.999999f * h.next[a]) + 1.0e-6f);
        Float next = dr::select(h.next[a] <= h.tmin, pushed, h.next[a]);
        h.tmin = dr::select(along[a], next, h.tmin);
        h.next[a] = dr::select(along[a], next + Float(h.dim) * h.delta[a], h.next[a]);
        h.voxel[a] = dr::select(along[a], h.voxel[a] + h.dim * h.step[a], h.voxel[a]);
    }
    return active & (h.tmin <= h.tmax);
}

/// PNanoVDB: pnanovdb_hdda_ray_clip. Clips [tmin, tmax] to the box
/// [bbox_min, bbox_max] (floats, e.g. an index box's min and max + 1);
/// returns whether the ray's line meets the box.
template <typename Float>
dr::mask_t<Float> hdda_ray_clip(const dr::Array<Float, 3> &bbox_min,
                                const dr::Array<Float, 3> &bbox_max,
                                const dr::Array<Float, 3> &origin, Float &tmin,
                                const dr::Array<Float, 3> &direction, Float &tmax) {
    // pnanovdb_min / pnanovdb_max: a < b ? a : b, a > b ? a : b (NaN: b)
    auto min_ = [](const Float &a, const Float &b) { return dr::select(a < b, a, b); };
    auto max_ = [](const Float &a, const Float &b) { return dr::select(a > b, a, b); };
    dr::Array<Float, 3> dir_inv = Float(1.f) / direction;
    dr::Array<Float, 3> t0 = (bbox_min - origin) * dir_inv,
                        t1 = (bbox_max - origin) * dir_inv;
    dr::Array<Float, 3> tmin3, tmax3;
    for (int a = 0; a < 3; ++a) {
        tmin3[a] = min_(t0[a], t1[a]);
        tmax3[a] = max_(t0[a], t1[a]);
    }
    Float tnear = max_(tmin3.x(), max_(tmin3.y(), tmin3.z())),
          tfar = min_(tmax3.x(), min_(tmax3.y(), tmax3.z()));
    dr::mask_t<Float> hit = tnear <= tfar;
    tmin = max_(tmin, tnear);
    tmax = min_(tmax, tfar);
    return hit;
}

} // namespace nanovdb_drjit
