/*
    nanovdb_drjit/sampler.h -- beyond PNanoVDB: a grid on a backend, and the
    lookups a volume makes in it

    One GridSampler holds one grid as a backend holds it (its words, the
    readers the loader's plan chose, its box, its bounds, its majorant table)
    and answers the queries of a volume plugin in index space:

      nearest(voxel)       the value of a voxel (relative to the box minimum)
      trilinear(rel)       interpolation between voxel centres at an index
                           position rel (relative to the box minimum; values
                           sit at integers), with the weights and the order of
                           Dr.Jit's texture (gridvolume)
      stochastic_voxel(rel, u)
                           stochastic filtering (Pharr et al. 2024): the one
                           voxel to read so that, over u uniform in [0, 1)^3,
                           the expected value is the trilinear (or the cubic
                           B-spline) filter's at rel; read it with nearest()
      nearest3, trilinear3 the same for Vec3f grids
      stencil(rel)         the 8 corners of a trilinear lookup (their value
                           addresses, levels, coordinates and weights), for
                           lookups that read something else at each corner
                           (the spectral scales of a Vec3f grid)
      walk_begin/advance   the majorant walk (majorant_walk.h) through it

    Every lookup is clamped to max(); with `clamp` set, positions are kept in
    the box first (gridvolume's convention: the nearest edge voxel). Spaces:
    the plugin turns its points into index space (local or world -> index),
    and nothing here knows of Mitsuba.

    The class is a template on the backend's float type alone: float, an
    LLVM array or a CUDA array (Dr.Jit's AD arrays). A Mitsuba plugin, built
    for 13 variants, uses three instantiations of it, compiled once each in
    their own files (src/volumes/sampler_*.cpp: sampler_impl.h holds the
    definitions). Tested against PNanoVDB's reads (tests/test_sampler.cpp).
*/

#pragma once

// Every file that sees GridSampler must see Dr.Jit's SIMD packets: they give
// dr::Array<float, 3> its layout (padded to 4 floats with AVX), as in Mitsuba
// (mitsuba/core/vector.h), so that the plugin and the files that compile the
// lookups agree on where each member lies
#include <drjit/packet.h>
#include <nanovdb_drjit/fast_readers.h>
#include <nanovdb_drjit/majorant_walk.h>
#include <nanovdb_drjit/stencil.h>
#include <nanovdb_drjit/traverse.h>

#include <array>
#include <atomic>
#include <cstdlib>
#include <memory>
#include <string>
#include <type_traits>
#include <vector>

namespace nanovdb_drjit {

/// What count_lookups counts, per lane (see GridSampler::count)
enum class Counter : uint32_t {
    Lookup = 0,     ///< eval*() calls
    WalkStep,       ///< cells majorant walks entered ...
    WalkEmptyStep,  ///< ... of them with a bound of 0
    WalkStep8,      ///< ... 8, 32, 128 and 4096 voxels wide
    WalkStep32,
    WalkStep128,
    WalkStep4096,
    Walk,           ///< walks begun
    Count
};
inline constexpr const char *COUNTER_NAMES[(uint32_t) Counter::Count] = {
    "lookup_count",        "walk_step_count",     "walk_empty_step_count",
    "walk_step_8_count",   "walk_step_32_count",  "walk_step_128_count",
    "walk_step_4096_count", "walk_count"
};

/// floor() to int32 of index positions relative to a box minimum. Points
/// absurdly far outside the box are clamped first (a float beyond the int32
/// range has no int32 floor); they read the background either way.
/// The largest float below 2^31: index positions are kept within +-this
inline constexpr float INDEX_LIMIT = 2147483520.f;

template <typename Float>
DRJIT_INLINE dr::Array<dr::int32_array_t<Float>, 3> index_floor(const dr::Array<Float, 3> &rel) {
    return dr::floor2int<dr::Array<dr::int32_array_t<Float>, 3>>(
        dr::clip(rel, -INDEX_LIMIT, INDEX_LIMIT));
}

/// Three numbers in [0, 1) from the bits of an index position and a seed:
/// the offsets of a stochastic filter where no sampler provides them
/// (Volume::eval has none). PCG3D (Jarzynski and Olano, "Hash Functions for
/// GPU Rendering", JCGT 2020): every output bit depends on every input bit,
/// so positions a rounding apart get unrelated offsets, and the same
/// position always the same ones.
template <typename Float>
DRJIT_INLINE dr::Array<Float, 3> hash_offsets(const dr::Array<Float, 3> &rel, uint32_t seed) {
    using UInt32 = dr::uint32_array_t<Float>;
    dr::Array<UInt32, 3> v;
    for (int k = 0; k < 3; ++k)
        v[k] = dr::reinterpret_array<UInt32>(rel[k]) * 1664525u + (1013904223u ^ (seed * (k + 1)));
    for (int round = 0; round < 2; ++round) {
        v[0] += v[1] * v[2];
        v[1] += v[2] * v[0];
        v[2] += v[0] * v[1];
        if (round == 0)
            for (int k = 0; k < 3; ++k)
                v[k] ^= dr::sr<16>(v[k]);
    }
    // 24 bits each: exactly representable, strictly below 1
    dr::Array<Float, 3> u;
    for (int k = 0; k < 3; ++k)
        u[k] = Float(dr::sr<8>(v[k])) * 0x1p-24f;
    return u;
}

template <typename Float> class GridSampler {
public:
    using UInt32 = dr::uint32_array_t<Float>;
    using Int32 = dr::int32_array_t<Float>;
    using UInt64 = dr::uint64_array_t<Float>;
    using Mask = dr::mask_t<Float>;
    using Vector3f = dr::Array<Float, 3>;
    using Vector3i = dr::Array<Int32, 3>;
    using Walk = MajorantWalk<Float>;
    /// A host block of 32-bit words (64-byte aligned, freed with std::free)
    using HostBlock = std::unique_ptr<uint32_t[], void (*)(void *)>;
    /// The grid's words on the backend: a JIT array (LLVM: mapped host
    /// memory; CUDA: device memory), or the host block itself on scalars
    using Buffer = std::conditional_t<dr::is_jit_v<Float>, UInt32, HostBlock>;
    /// Per-value scales of a spectral Vec3f grid: a JIT array or a host vector
    using Scales = std::conditional_t<dr::is_jit_v<Float>, Float, std::vector<float>>;

    /// The 8 corners of a trilinear lookup, corner = i + 2 j + 4 k (x fastest)
    struct Stencil {
        StencilAddresses<UInt32> corners;
        Coord<UInt32> ijk0;              ///< corner 0's absolute coordinate
        dr::Array<Float, 8> weight;      ///< in Dr.Jit's texture's arithmetic
    };

    GridSampler() : grid(empty_buffer()) { }
    GridSampler(GridSampler &&) = default;
    GridSampler &operator=(GridSampler &&) = default;

    // ---- Set up, once, from what the loader prepared -----------------------

    /// Takes over `host` (word_count words): the buffer on scalar variants,
    /// mapped in place on LLVM, uploaded (and freed) on CUDA
    void set_grid(HostBlock host, size_t word_count);

    /// The box [index_min, index_min + resolution) the lookups clamp to
    /// (clamp), and the grid type they read
    void set_box(const int32_t index_min[3], const int32_t resolution[3], uint32_t grid_type,
                 bool clamp);

    /// max() (every lookup is clamped to it) and, for Vec3f, per channel
    void set_bounds(float max, const float max3[3]);

    /// Spectral Vec3f grids: the scale of every value (see the loader's
    /// spectral rewrite): leaf values (512 per leaf), then the root tiles,
    /// then the background; internal tiles keep theirs in the entry's 4th word
    void set_scales(std::vector<float> scales, uint32_t tiles_begin, uint32_t leaf_begin_word,
                    uint32_t tile_begin_word);

    /// Index grids (OnIndex): the value of every index but 0, index i at
    /// values[i - 1] (`channels` 3: the floats values[3 (i - 1) + c], read
    /// by nearest3 / trilinear3), and the background (index 0, per
    /// channel); `count` floats. On JIT backends the values are a Float
    /// array that lookups gather from: differentiable
    void set_index_values(const float *values, size_t count, const std::array<float, 3> &background,
                          uint32_t channels = 1);

    /// count_lookups: start counting (one atomic add per counted lane)
    void enable_counters();

    // ---- Lookups ------------------------------------------------------------

    /// The value of `voxel` (relative to the box minimum)
    Float nearest(const Vector3i &voxel, const Mask &active) const;

    /// Trilinear interpolation at the index position `rel` (relative to the
    /// box minimum, values at integers)
    Float trilinear(const Vector3f &rel, const Mask &active) const;

    /// The voxel (relative to the box minimum) a stochastic filter reads at
    /// the index position `rel` (as trilinear()'s) for offsets u in
    /// [0, 1)^3: per axis, with b = floor(rel) and t = rel - b,
    ///   trilinear: b + 1 with probability t, else b;
    ///   tricubic:  b - 1 + k with probability B_k(t), the uniform cubic
    ///              B-spline's weights (k = 0..3; a reach of 1.5 voxels)
    /// so that the expected nearest() value is the filter's (B-spline
    /// weights are non-negative and sum to 1: no value exceeds max())
    Vector3i stochastic_voxel(const Vector3f &rel, const Vector3f &u, bool tricubic) const;

    /// Vec3f grids (and index grids of 3 channels): each channel clamped to its max
    Vector3f nearest3(const Vector3i &voxel, const Mask &active) const;
    Vector3f trilinear3(const Vector3f &rel, const Mask &active) const;

    /// Where a trilinear lookup at `rel` reads (Vec3f grids)
    Stencil stencil3(const Vector3f &rel, const Mask &active) const;

    /// Value address and level of `voxel` (relative; Vec3f grids)
    AddressAndLevel<UInt32> address3(const Vector3i &voxel, const Mask &active) const;

    /// The 3-vector at a value address (Vec3f grids)
    Vector3f read3(const UInt32 &address, const Mask &active) const;

    /// The scale of a spectral Vec3f value from its address and level
    Float value_scale(const UInt32 &address, const UInt32 &level, const Coord<UInt32> &ijk,
                      const Mask &active) const;

    /// The absolute coordinate of a voxel given relative to the box minimum
    /// (int32 wrap-around, as the VDB index space)
    Coord<UInt32> absolute(const Vector3i &voxel) const;

    // ---- Leaves (emission sampling: src/media/emission_distribution.h) ------

    /// Whether leaf_at and leaf_origin address this grid's leaves: fixed-size
    /// leaves (every type but FpN)
    bool leaves_addressable() const;

    /// PNanoVDB's value address (in words) and level of the absolute
    /// coordinate `ijk`: a leaf's value, a tile's (nanovdb_loader/
    /// active_tiles.h names tiles by it) or the background's
    AddressAndLevel<UInt32> value_address_at(const Coord<UInt32> &ijk,
                                             const Mask &active) const;

    /// The leaf (its place in the leaf array) whose value `al` addresses,
    /// and where it is one (else 0 and false)
    std::pair<UInt32, Mask> leaf_of(const AddressAndLevel<UInt32> &al, const Mask &active) const;

    /// Leaf `leaf`'s origin (absolute, a multiple of 8 per axis)
    Coord<UInt32> leaf_origin(const UInt32 &leaf, const Mask &active) const;

    // ---- The majorant walk, in cell space (majorant_walk.h) -----------------

    /// controls: the walk also gives each cell's control and lower bound
    /// (MajorantWalk::control, minorant), for residual ratio tracking
    Walk walk_begin(const Vector3f &origin, const Vector3f &direction, const Float &tmin,
                    const Float &tmax, const Float &coarse_limit, const Mask &active,
                    bool controls = false) const;
    Mask walk_advance(Walk &walk, const Vector3f &origin, const Vector3f &direction,
                      const Float &coarse_limit, const Mask &active, bool controls = false) const;

    // ---- Counters -----------------------------------------------------------

    void count(Counter which, const Mask &active) const;
    /// The counts so far (reads the backend)
    std::vector<uint64_t> counter_values() const;
    bool counting() const { return m_counting; }

    // ---- State --------------------------------------------------------------

    Buffer grid;                   ///< the grid's words
    Reader<UInt32> reader;         ///< the readers of the loader's plan
    MajorantGrid<UInt32> majorants; ///< per-node bounds (the walk)
    uint32_t grid_type = 0;        ///< NanoVDB's GridType (layout.h)
    bool clamp = false;            ///< positions kept in the box (wrap_mode "clamp")
    Vector3i index_min;            ///< the box minimum (absolute)
    Vector3i last_voxel;           ///< the box extent - 1
    Float max;                     ///< the clamp of every lookup
    Vector3f max3;                 ///< ... of each channel (Vec3f)
    Scales scales;                 ///< spectral Vec3f: each value's scale
    Scales index_values;           ///< index grids: value index i + 1's value at i
    Vector3f index_background;     ///< index grids: index 0's value (per channel)
    uint32_t index_channels = 1;   ///< index grids: floats a value (1 or 3)
    UInt32 scale_tiles, scale_background, leaf_begin_word, tile_begin_word;

    NVDB_TRAVERSE(grid, reader, majorants, index_min, last_voxel, max, max3, scales,
                  index_values, index_background,
                  scale_tiles, scale_background, leaf_begin_word, tile_begin_word, m_counters)

private:
    static Buffer empty_buffer() {
        if constexpr (dr::is_jit_v<Float>)
            return UInt32();
        else
            return Buffer(nullptr, std::free);
    }

    /// The grid as the translation reads it: a JIT array or a host pointer
    decltype(auto) words() const {
        if constexpr (dr::is_jit_v<Float>)
            return (const UInt32 &) grid;
        else
            return static_cast<const uint32_t *>(grid.get());
    }

    Vector3i clamp_voxel(const Vector3i &voxel) const;
    Vector3f clamp_position(const Vector3f &rel) const;
    /// The value at an absolute coordinate (scalar types), clamped to max
    Float value_at(const Coord<UInt32> &ijk, const Mask &active) const;
    /// Index grids: the value of a value index (0: the background)
    Float indexed_value(const UInt32 &index, const Mask &active) const;
    /// ... of 3 channels
    Vector3f indexed_value3(const UInt32 &index, const Mask &active) const;
    /// Index grids of 3 channels: the value index of an absolute coordinate
    UInt32 index_at(const Coord<UInt32> &ijk, const Mask &active) const;
    bool vec3_index() const { return grid_type == layout::GRID_TYPE_ONINDEX && index_channels == 3; }
    /// The value at a value address and level (scalar types and index grids)
    template <uint32_t T, typename Buf>
    Float read_value(const Buf &buf, const UInt32 &address, const UInt32 &level,
                     const Coord<UInt32> &ijk, const Mask &active) const;
    void count_step(const Walk &walk, const Mask &active) const;

    bool m_counting = false;
    mutable UInt64 m_counters;     ///< JIT: per Counter
    std::shared_ptr<std::atomic<uint64_t>[]> m_scalar_counters; ///< scalar: per Counter
};

} // namespace nanovdb_drjit
