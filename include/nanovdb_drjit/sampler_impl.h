/*
    nanovdb_drjit/sampler_impl.h -- GridSampler's definitions (sampler.h)

    Included by the files that instantiate GridSampler for a backend
    (src/volumes/sampler_*.cpp) and by the tests, not by the plugin, so that
    each backend's lookups are compiled once.
*/

#pragma once

#include <nanovdb_drjit/backend_buffer.h>
#include <nanovdb_drjit/sampler.h>

#include <cstring>

namespace nanovdb_drjit {

// ---------------------------------------------------------------------------
//  Set up
// ---------------------------------------------------------------------------

template <typename Float>
void GridSampler<Float>::set_grid(HostBlock host, size_t word_count) {
    if constexpr (!dr::is_jit_v<Float>) {
        (void) word_count;
        grid = std::move(host);
    } else if constexpr (dr::backend_v<Float> == JitBackend::LLVM) {
        grid = UInt32::steal(backend::map_host_words(host.release(), word_count));
    } else {
        grid = UInt32::steal(backend::upload_cuda_words(host.get(), word_count));
    }
}

template <typename Float>
void GridSampler<Float>::set_box(const int32_t min_[3], const int32_t resolution[3],
                                 uint32_t type, bool clamp_) {
    grid_type = type;
    clamp = clamp_;
    // Per-grid values reach kernels as opaque variables, so that another
    // grid does not recompile them
    for (int k = 0; k < 3; ++k) {
        index_min[k] = dr::opaque<Int32>(min_[k]);
        last_voxel[k] = dr::opaque<Int32>(resolution[k] - 1);
    }
}

template <typename Float>
void GridSampler<Float>::set_bounds(float max_, const float max3_[3]) {
    max = dr::opaque<Float>(max_);
    for (int k = 0; k < 3; ++k)
        max3[k] = dr::opaque<Float>(max3_[k]);
}

template <typename Float>
void GridSampler<Float>::set_scales(std::vector<float> s, uint32_t tiles_begin,
                                    uint32_t leaf_begin, uint32_t tile_begin) {
    scale_tiles = dr::opaque<UInt32>(tiles_begin);
    scale_background = dr::opaque<UInt32>(uint32_t(s.size() - 1));
    leaf_begin_word = dr::opaque<UInt32>(leaf_begin);
    tile_begin_word = dr::opaque<UInt32>(tile_begin);
    if constexpr (dr::is_jit_v<Float>)
        scales = dr::load<Float>(s.data(), s.size());
    else
        scales = std::move(s);
}

template <typename Float>
void GridSampler<Float>::set_index_values(const float *values, size_t count,
                                          const std::array<float, 3> &background,
                                          uint32_t channels) {
    for (int k = 0; k < 3; ++k)
        index_background[k] = dr::opaque<Float>(background[k]);
    index_channels = channels;
    if constexpr (dr::is_jit_v<Float>)
        index_values = dr::load<Float>(values, count);
    else
        index_values.assign(values, values + count);
}

template <typename Float> void GridSampler<Float>::enable_counters() {
    m_counting = true;
    constexpr uint32_t n = (uint32_t) Counter::Count;
    if constexpr (dr::is_jit_v<Float>) {
        m_counters = dr::zeros<UInt64>(n);
        dr::make_opaque(m_counters);
    } else {
        m_scalar_counters.reset(new std::atomic<uint64_t>[n]);
        for (uint32_t i = 0; i < n; ++i)
            m_scalar_counters[i] = 0;
    }
}

// ---------------------------------------------------------------------------
//  Lookups
// ---------------------------------------------------------------------------

/// A lookup clamped to max(): the clamp is for the majorant (a few ulps of
/// rounded weights, or values beyond the volume's box), not part of the
/// function, so under AD its derivative is the unclamped lookup's (as
/// gridvolume's, which has no clamp): value + detach(min(value, max) - value)
template <typename T, typename M> DRJIT_INLINE T clamp_to_max(const T &value, const M &max) {
    if constexpr (dr::is_diff_v<T>)
        return value + dr::detach(dr::minimum(value, max) - value);
    else
        return dr::minimum(value, max);
}

template <typename Float>
typename GridSampler<Float>::Vector3i
GridSampler<Float>::clamp_voxel(const Vector3i &voxel) const {
    return clamp ? dr::clip(voxel, 0, last_voxel) : voxel;
}

/// Keeping a trilinear position between the edge voxels' centres gives the
/// value of clamping each corner of its stencil, as Dr.Jit's texture does
/// (up to the rounding of weights that sum to 1). Without clamp, a position
/// beyond the int32 range is kept at its edge, as index_floor keeps its
/// floor: the weights (rel - floor) stay in [0, 1] (else 128 and -127, and a
/// negative lookup)
template <typename Float>
typename GridSampler<Float>::Vector3f
GridSampler<Float>::clamp_position(const Vector3f &rel) const {
    return clamp ? dr::clip(rel, 0.f, Vector3f(last_voxel))
                 : dr::clip(rel, -INDEX_LIMIT, INDEX_LIMIT);
}

template <typename Float>
Coord<typename GridSampler<Float>::UInt32>
GridSampler<Float>::absolute(const Vector3i &voxel) const {
    // int32 wrap-around on every backend (plain C++ int32 overflow is undefined)
    Coord<UInt32> out;
    for (int k = 0; k < 3; ++k)
        out[k] = dr::reinterpret_array<Int32>(UInt32(dr::reinterpret_array<UInt32>(voxel[k]) +
                                                     dr::reinterpret_array<UInt32>(index_min[k])));
    return out;
}

template <typename Float>
Float GridSampler<Float>::indexed_value(const UInt32 &index, const Mask &active) const {
    Mask stored = active & (index != 0u);
    Float value;
    if constexpr (dr::is_jit_v<Float>)
        value = dr::width(index_values) == 0 // (a grid without values: all background)
                    ? Float(0.f)
                    : dr::gather<Float>(index_values, UInt32(index - 1u), stored);
    else
        value = stored ? index_values[index - 1u] : 0.f;
    // (inactive lanes return 0, as every read does)
    return dr::select(stored, value, dr::select(active, index_background[0], Float(0.f)));
}

template <typename Float>
typename GridSampler<Float>::Vector3f
GridSampler<Float>::indexed_value3(const UInt32 &index, const Mask &active) const {
    Mask stored = active & (index != 0u);
    Vector3f value;
    if constexpr (dr::is_jit_v<Float>) {
        // (value i's 3 floats from 3 i: a gather of Vector3f; under AD its
        // adjoint scatters each channel's gradient to its own float)
        value = dr::width(index_values) == 0
                    ? Vector3f(0.f)
                    : dr::gather<Vector3f>(index_values, UInt32(index - 1u), stored);
    } else {
        if (stored)
            for (uint32_t k = 0; k < 3; ++k)
                value[k] = index_values[3 * (index - 1u) + k];
        else
            value = Vector3f(0.f);
    }
    return dr::select(stored, value, dr::select(active, index_background, Vector3f(0.f)));
}

template <typename Float>
typename GridSampler<Float>::UInt32
GridSampler<Float>::index_at(const Coord<UInt32> &ijk, const Mask &active) const {
    constexpr uint32_t T = layout::GRID_TYPE_ONINDEX;
    return reader.apply(words(), [&](const auto &buf, const auto &root) {
        AddressAndLevel<UInt32> al = value_address_and_level<T>(buf, root, ijk, active);
        return root_read_index<T>(buf, al.address, al.level, ijk, active);
    });
}

template <typename Float>
template <uint32_t T, typename Buf>
Float GridSampler<Float>::read_value(const Buf &buf, const UInt32 &address, const UInt32 &level,
                                     const Coord<UInt32> &ijk, const Mask &active) const {
    if constexpr (grid_type_traits<T>::type.codec == layout::LeafCodec::OnIndex)
        return indexed_value(root_read_index<T>(buf, address, level, ijk, active), active);
    else
        return root_read_float<T>(buf, address, level, ijk, active);
}

template <typename Float>
Float GridSampler<Float>::value_at(const Coord<UInt32> &ijk, const Mask &active) const {
    Float value = layout::visit_value_type<false>(grid_type, [&](auto type) {
        constexpr uint32_t T = decltype(type)::value;
        return reader.apply(words(), [&](const auto &buf, const auto &root) {
            AddressAndLevel<UInt32> al = value_address_and_level<T>(buf, root, ijk, active);
            return read_value<T>(buf, al.address, al.level, ijk, active);
        });
    });
    return clamp_to_max(value, max);
}

template <typename Float>
Float GridSampler<Float>::nearest(const Vector3i &voxel, const Mask &active) const {
    count(Counter::Lookup, active);
    return value_at(absolute(clamp_voxel(voxel)), active);
}

template <typename Float>
Float GridSampler<Float>::trilinear(const Vector3f &rel_, const Mask &active) const {
    count(Counter::Lookup, active);
    Vector3f rel = clamp_position(rel_);
    Vector3i base = dr::floor2int<Vector3i>(rel); // (rel in the int32 range already)
    Vector3f w1 = rel - Vector3f(base), w0 = 1.f - w1;
    Coord<UInt32> c = absolute(base);
    Float result = layout::visit_value_type<false>(grid_type, [&](auto type) {
        constexpr uint32_t T = decltype(type)::value;
        // Levels: only the quantized and half readers need them
        constexpr bool with_level = grid_type_traits<T>::type.codec != layout::LeafCodec::Float32;
        StencilAddresses<UInt32> corners = reader.apply(words(), [&](const auto &buf,
                                                                     const auto &root) {
            return root_get_stencil<T, with_level>(buf, root, c, active);
        });
        // The 8 corners summed in the order and with the weights of Dr.Jit's texture
        Float sum = 0.f;
        for (uint32_t corner = 0; corner < 8; ++corner) {
            Float weight = 1.f;
            for (uint32_t k = 0; k < 3; ++k)
                weight = weight * (((corner >> k) & 1) ? w1[k] : w0[k]);
            Coord<UInt32> ijk = coord_add<UInt32>(c, corner & 1u, (corner >> 1) & 1u,
                                                  (corner >> 2) & 1u);
            Float value = read_value<T>(words(), corners.address[corner],
                                        corners.level[corner], ijk, active);
            sum = dr::fmadd(value, weight, sum);
        }
        return sum;
    });
    // The rounded weights can sum to slightly more than 1, so the result
    // could exceed the largest corner by a few ulps (measured: 3 ulps on a
    // level set whose values sit at its maximum); and corners outside the
    // volume's box may hold more than max(). A majorant must bound every
    // lookup, so clamp.
    return clamp_to_max(result, max);
}

template <typename Float> bool GridSampler<Float>::leaves_addressable() const {
    const layout::GridTypeConstants *c = layout::grid_type_constants(grid_type);
    return c && grid_type != layout::GRID_TYPE_FPN;
}

template <typename Float>
std::pair<typename GridSampler<Float>::UInt32, typename GridSampler<Float>::Mask>
GridSampler<Float>::leaf_of(const AddressAndLevel<UInt32> &al, const Mask &active) const {
    const uint32_t leaf_words = layout::grid_type_constants(grid_type)->leaf_size / 4;
    // Leaves are one array of fixed stride: the value's address is in its leaf
    const Mask in_leaf = active && al.level == LEVEL_LEAF;
    const UInt32 leaf = (al.address - majorants.leaf_begin) / leaf_words;
    return { dr::select(in_leaf, leaf, 0u), in_leaf };
}

template <typename Float>
AddressAndLevel<typename GridSampler<Float>::UInt32>
GridSampler<Float>::value_address_at(const Coord<UInt32> &ijk, const Mask &active) const {
    return layout::visit_value_type(grid_type, [&](auto type) {
        constexpr uint32_t T = decltype(type)::value;
        return reader.apply(words(), [&](const auto &buf, const auto &root) {
            return value_address_and_level<T>(buf, root, ijk, active);
        });
    });
}

template <typename Float>
Coord<typename GridSampler<Float>::UInt32>
GridSampler<Float>::leaf_origin(const UInt32 &leaf, const Mask &active) const {
    const uint32_t leaf_words = layout::grid_type_constants(grid_type)->leaf_size / 4;
    // PNanoVDB: pnanovdb_leaf_get_bbox_min, masked to the leaf's origin
    const UInt32 address = majorants.leaf_begin + leaf * leaf_words + layout::LEAF_OFF_BBOX_MIN / 4;
    Coord<UInt32> o;
    for (uint32_t k = 0; k < 3; ++k)
        o[k] = dr::reinterpret_array<Int32>(read_uint32(words(), UInt32(address + k), active) &
                                            ~7u);
    return o;
}

template <typename Float>
typename GridSampler<Float>::Vector3i
GridSampler<Float>::stochastic_voxel(const Vector3f &rel_, const Vector3f &u,
                                     bool tricubic) const {
    Vector3f rel = clamp_position(rel_);
    Vector3i base = dr::floor2int<Vector3i>(rel); // (rel in the int32 range already)
    Vector3f t = rel - Vector3f(base);
    if (!tricubic) // u >= 1 - t: probability t
        return dr::select(u + t >= 1.f, base + Vector3i(1), base);
    // The B-spline's weights, accumulated: tap k is chosen where u lies in
    // [c_{k-1}, c_k), c_3 = 1
    Vector3f s = 1.f - t, t2 = t * t, t3 = t2 * t;
    Vector3f c0 = s * s * s * (1.f / 6.f),
             c1 = c0 + (3.f * t3 - 6.f * t2 + 4.f) * (1.f / 6.f),
             c2 = 1.f - t3 * (1.f / 6.f);
    const Vector3i one(1), zero(0);
    Vector3i k = dr::select(u >= c0, one, zero) + dr::select(u >= c1, one, zero) +
                 dr::select(u >= c2, one, zero) - one;
    return base + k;
}

template <typename Float>
AddressAndLevel<typename GridSampler<Float>::UInt32>
GridSampler<Float>::address3(const Vector3i &voxel, const Mask &active) const {
    constexpr uint32_t T = layout::GRID_TYPE_VEC3F;
    Coord<UInt32> ijk = absolute(clamp_voxel(voxel));
    return reader.apply(words(), [&](const auto &buf, const auto &root) {
        return value_address_and_level<T>(buf, root, ijk, active);
    });
}

template <typename Float>
typename GridSampler<Float>::Vector3f GridSampler<Float>::read3(const UInt32 &address,
                                                                const Mask &active) const {
    return root_read_vec3f<layout::GRID_TYPE_VEC3F>(words(), address, active);
}

template <typename Float>
typename GridSampler<Float>::Vector3f
GridSampler<Float>::nearest3(const Vector3i &voxel, const Mask &active) const {
    count(Counter::Lookup, active);
    if (vec3_index())
        return clamp_to_max(indexed_value3(index_at(absolute(clamp_voxel(voxel)), active), active),
                            max3);
    return clamp_to_max(read3(address3(voxel, active).address, active), max3);
}

template <typename Float>
typename GridSampler<Float>::Stencil GridSampler<Float>::stencil3(const Vector3f &rel_,
                                                                  const Mask &active) const {
    Vector3f rel = clamp_position(rel_);
    Vector3i base = dr::floor2int<Vector3i>(rel); // (rel in the int32 range already)
    Vector3f w1 = rel - Vector3f(base), w0 = 1.f - w1;
    Stencil s;
    s.ijk0 = absolute(base);
    s.corners = reader.apply(words(), [&](const auto &buf, const auto &root) {
        // (an index grid's corners: the addresses of their indices)
        return vec3_index()
                   ? root_get_stencil<layout::GRID_TYPE_ONINDEX, true>(buf, root, s.ijk0, active)
                   : root_get_stencil<layout::GRID_TYPE_VEC3F, true>(buf, root, s.ijk0, active);
    });
    for (uint32_t corner = 0; corner < 8; ++corner) {
        Float weight = 1.f;
        for (uint32_t k = 0; k < 3; ++k)
            weight = weight * (((corner >> k) & 1) ? w1[k] : w0[k]);
        s.weight[corner] = weight;
    }
    return s;
}

template <typename Float>
typename GridSampler<Float>::Vector3f
GridSampler<Float>::trilinear3(const Vector3f &rel, const Mask &active) const {
    count(Counter::Lookup, active);
    Stencil s = stencil3(rel, active);
    Vector3f sum(0.f);
    for (uint32_t corner = 0; corner < 8; ++corner) {
        Vector3f value;
        if (vec3_index()) {
            Coord<UInt32> ijk = coord_add<UInt32>(s.ijk0, corner & 1u, (corner >> 1) & 1u,
                                                  (corner >> 2) & 1u);
            value = indexed_value3(root_read_index<layout::GRID_TYPE_ONINDEX>(
                                       words(), s.corners.address[corner],
                                       s.corners.level[corner], ijk, active),
                                   active);
        } else {
            value = read3(s.corners.address[corner], active);
        }
        sum = dr::fmadd(value, s.weight[corner], sum);
    }
    return clamp_to_max(sum, max3);
}

template <typename Float>
Float GridSampler<Float>::value_scale(const UInt32 &address, const UInt32 &level,
                                      const Coord<UInt32> &ijk, const Mask &active) const {
    constexpr const auto &c = grid_type_traits<layout::GRID_TYPE_VEC3F>::constants;
    Mask leaf = active & (level == LEVEL_LEAF),
         entry = active & ((level == LEVEL_LOWER) | (level == LEVEL_UPPER)),
         tile = active & (level == LEVEL_ROOT_TILE),
         background = active & (level == LEVEL_BACKGROUND);
    UInt32 n = leaf_coord_to_offset(ijk);
    const dr::divisor<uint32_t> leaf_words(c.leaf_size / 4);
    UInt32 leaf_word = address - (c.leaf_off_table / 4) - 3u * n;
    UInt32 index = leaf_words(UInt32(leaf_word - leaf_begin_word)) * 512u + n;
    index = dr::select(tile, scale_tiles + ((address - tile_begin_word -
                                             c.root_tile_off_value / 4) >> 3), index);
    index = dr::select(background, scale_background, index);
    Float from_array;
    if constexpr (dr::is_jit_v<Float>)
        from_array = dr::gather<Float>(scales, index, leaf | tile | background);
    else
        from_array = (leaf | tile | background) ? scales[index] : 0.f;
    // Internal tiles keep their scale in the entry's fourth word
    Float from_entry = read_float(words(), UInt32(address + 3u), entry);
    return dr::select(entry, from_entry, from_array);
}

// ---------------------------------------------------------------------------
//  The majorant walk
// ---------------------------------------------------------------------------

template <typename Float>
typename GridSampler<Float>::Walk
GridSampler<Float>::walk_begin(const Vector3f &origin, const Vector3f &direction,
                               const Float &tmin, const Float &tmax, const Float &coarse_limit,
                               const Mask &active, bool controls) const {
    Walk walk = layout::visit_value_type(grid_type, [&](auto type) {
        return reader.apply(words(), [&](const auto &buf, const auto &root) {
            return nanovdb_drjit::walk_begin<decltype(type)::value>(
                buf, root, majorants, origin, direction, tmin, tmax, coarse_limit, active,
                controls);
        });
    });
    count(Counter::Walk, active);
    count_step(walk, active && walk_valid(walk));
    return walk;
}

template <typename Float>
typename GridSampler<Float>::Mask
GridSampler<Float>::walk_advance(Walk &walk, const Vector3f &origin, const Vector3f &direction,
                                 const Float &coarse_limit, const Mask &active,
                                 bool controls) const {
    Mask more = layout::visit_value_type(grid_type, [&](auto type) {
        return reader.apply(words(), [&](const auto &buf, const auto &root) {
            return nanovdb_drjit::walk_advance<decltype(type)::value>(
                buf, root, majorants, walk, origin, direction, coarse_limit, active, controls);
        });
    });
    count_step(walk, more);
    return more;
}

// ---------------------------------------------------------------------------
//  Counters
// ---------------------------------------------------------------------------

template <typename Float>
void GridSampler<Float>::count(Counter which, const Mask &active) const {
    if (!m_counting)
        return;
    if constexpr (dr::is_jit_v<Float>)
        dr::scatter_reduce(ReduceOp::Add, m_counters, UInt64(1), UInt32((uint32_t) which),
                           active);
    else if (active)
        m_scalar_counters[(uint32_t) which].fetch_add(1, std::memory_order_relaxed);
}

/// A cell the walk entered: counted, by its bound (zero or not) and size
template <typename Float>
void GridSampler<Float>::count_step(const Walk &walk, const Mask &active) const {
    if (!m_counting)
        return;
    count(Counter::WalkStep, active);
    count(Counter::WalkEmptyStep, active && walk.majorant == 0.f);
    const int32_t dims[4] = { 8, 32, 128, 4096 };
    for (int i = 0; i < 4; ++i)
        count(Counter((uint32_t) Counter::WalkStep8 + i), active && walk.cell_size() == dims[i]);
}

template <typename Float> std::vector<uint64_t> GridSampler<Float>::counter_values() const {
    std::vector<uint64_t> out((uint32_t) Counter::Count, 0);
    if (!m_counting)
        return out;
    if constexpr (dr::is_jit_v<Float>) {
        dr::eval(m_counters);
        dr::store(out.data(), m_counters);
    } else {
        for (size_t i = 0; i < out.size(); ++i)
            out[i] = m_scalar_counters[i].load();
    }
    return out;
}

} // namespace nanovdb_drjit
