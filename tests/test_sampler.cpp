/*
    nanovdb_drjit::GridSampler (include/nanovdb_drjit/sampler.h), set up as
    the plugin sets it up (nanovdbvolume's load(): the loader's prepare_grid,
    the reader plan, the majorant table, set_bounds, set_grid, set_box),
    against PNanoVDB's reads of the same decoded bytes (Debian's
    libnanovdb-dev, compiled here as C):

      - nearest(voxel) is PNanoVDB's value at index_min + voxel, clamped to
        max(); with clamp the voxel is first kept in the box (the nearest
        edge voxel), without it the tree's value (or the background) is read;
      - trilinear(rel) is the sum of 8 PNanoVDB reads with the weights, in
        the order and with the rounding of sampler_impl.h (Dr.Jit's texture:
        weight = ((1 w_x) w_y) w_z, summed by fused multiply-adds, corner
        = i + 2 j + 4 k): bit for bit, on positions inside the box, across
        leaf and node boundaries and outside the box;
      - a max() below the values clamps every lookup;
      - stochastic_voxel: every voxel it picks lies in the filter's reach, and
        the mean of nearest() over uniform offsets is the trilinear value, or
        the cubic B-spline's (64 PNanoVDB reads), within 5 standard errors;
      - nearest3 / trilinear3 on Vec3f grids, each channel clamped to its max;
      - counters count the active lanes of every lookup, and inactive lanes
        return 0 and read nothing (a grid of PROT_NONE memory).

    Float grids (every test grid), Half, Fp8 and FpN versions of four of
    them, Vec3f versions of four; scalar and LLVM (the plugin's DiffArray
    type); CUDA only where a GPU and libcuda are present.

    The reference arithmetic is written out here with std::fmaf where
    sampler_impl.h calls dr::fmadd (fused on every backend), and the project
    builds with -ffp-contract=off, so the comparisons are exact.
*/

#define PNANOVDB_C
#define PNANOVDB_ADDRESS_64
#include <nanovdb/PNanoVDB.h>

// Dr.Jit's packets first (see sampler.h), then the definitions, compiled here
// for each backend as src/volumes/sampler_*.cpp compile them for the plugin
#include <drjit/packet.h>
#include <drjit/autodiff.h>
#include <nanovdb_drjit/sampler.h>
#include <nanovdb_loader/load.h>
#include <volumes/sampler_setup.h>
#include <drjit/jit.h>
#include <drjit-core/jit.h>

#include <doctest/doctest.h>
#include <backends.h>
#include <grids.h>
#include <guarded_buffer.h>
#include <typed_grids.h>
#include "testdata/seeded.h"

#include <algorithm>
#include <array>
#include <cfloat>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace ndr = nanovdb_drjit;
namespace loader = nanovdb_loader;
namespace dr = drjit;
using nvdb_test::cuda_available;
using nvdb_test::init_backend;

using LLVMFloat = dr::DiffArray<JitBackend::LLVM, float>;
using CUDAFloat = dr::DiffArray<JitBackend::CUDA, float>;

// The plugin's own lookups: the objects of src/volumes/sampler_*.cpp (the
// nanovdb_sampler library), linked here as into the plugin, not compiled again
extern template class nanovdb_drjit::GridSampler<float>;
extern template class nanovdb_drjit::GridSampler<LLVMFloat>;
#if NVDB_TEST_CUDA
extern template class nanovdb_drjit::GridSampler<CUDAFloat>;
#endif

namespace {

using Coord3 = std::array<int32_t, 3>;
using Pos3 = std::array<float, 3>;

/// Lookups per grid and mode (seeded coordinates, plus the edge positions)
constexpr size_t QUERY_COUNT = 20000;

uint32_t bits_of(float f) {
    uint32_t b;
    std::memcpy(&b, &f, 4);
    return b;
}

/// int32 wrap-around, written in uint32 (defined behaviour)
int32_t wrap_add(int32_t a, int32_t b) { return int32_t(uint32_t(a) + uint32_t(b)); }
int32_t wrap_sub(int32_t a, int32_t b) { return int32_t(uint32_t(a) - uint32_t(b)); }

// ---------------------------------------------------------------------------
//  The test grids, as the bytes a file would hold (built once)
// ---------------------------------------------------------------------------

struct Source {
    std::string label;             ///< "noisy_cloud (fp8)"
    std::vector<uint32_t> words;   ///< the grid as written
    uint64_t bytes = 0;
    std::vector<Coord3> coords;    ///< query_coords() of its float topology
};

Source make_source(const std::string &name, const std::string &type, uint64_t seed) {
    Source s;
    s.label = type == "float" ? name : name + " (" + type + ")";
    nanovdb::GridHandle<nanovdb::HostBuffer> float_grid;
    if (type == "float") {
        float_grid = nvdb_test::make_nano_grid(name);
        s.bytes = float_grid.size();
        s.words.resize((s.bytes + 3) / 4);
        std::memcpy(s.words.data(), float_grid.data(), s.bytes);
    } else {
        nvdb_test::TypedGrid t = nvdb_test::make_typed_grid(name, type);
        s.bytes = t.bytes;
        s.words = std::move(t.words);
        float_grid = std::move(t.float_grid);
    }
    s.coords = nvdb_test::query_coords(*float_grid.grid<float>(), QUERY_COUNT, seed);
    return s;
}

/// Float: every test grid. Scalar types: Half, Fp8 and FpN of four grids
/// with tiles at every level and a non-zero background between them.
const std::vector<Source> &scalar_sources() {
    static const std::vector<Source> all = [] {
        std::vector<Source> out;
        uint64_t seed = 700;
        for (const std::string &name : nvdb_test::grid_names())
            out.push_back(make_source(name, "float", seed++));
        for (const char *name : { "noisy_cloud", "lower_tiles", "upper_tiles", "nonzero_background" })
            for (const char *type : { "half", "fp8", "fpn" })
                if (nvdb_test::has_typed_grid(name, type))
                    out.push_back(make_source(name, type, seed++));
        return out;
    }();
    return all;
}

const std::vector<Source> &vec3_sources() {
    static const std::vector<Source> all = [] {
        std::vector<Source> out;
        uint64_t seed = 800;
        for (const char *name : { "noisy_cloud", "lower_tiles", "root_tiles_negative",
                                  "nonzero_background" })
            out.push_back(make_source(name, "vec3f", seed++));
        return out;
    }();
    return all;
}

/// A source by its label
const Source &source(const std::string &label) {
    for (const std::vector<Source> *all : { &scalar_sources(), &vec3_sources() })
        for (const Source &s : *all)
            if (s.label == label)
                return s;
    FAIL("no test source \"", label, "\"");
    throw std::logic_error("unreachable");
}

// ---------------------------------------------------------------------------
//  The plugin's set-up (nanovdbvolume's load(), without Mitsuba)
// ---------------------------------------------------------------------------

/// A sampler as nanovdbvolume holds one, and what the reference needs
template <typename Float> struct Loaded {
    ndr::GridSampler<Float> sampler;
    std::vector<uint32_t> words;   ///< the decoded grid, as the sampler holds it
    uint32_t grid_type = 0;
    int32_t index_min[3], resolution[3];
    float max = 0.f;
    std::array<float, 3> max3{};
};

/// prepare_grid's result for a source, computed once for the program (its
/// per-node majorants take most of the set-up's time): the decoded block and
/// the bounds the plugin takes from it
struct Prepared {
    std::unique_ptr<uint32_t[], void (*)(void *)> block{ nullptr, std::free };
    size_t backend_bytes = 0;          ///< the grid padded to 64 bytes, as the plugin's
    std::unique_ptr<loader::PreparedGrid> grid; ///< a view of `block`
};

/// nanovdbvolume's prepare_grid call (`ring`: the plugin's !nearest && !clamp;
/// `index_grid`: differentiable=true, the grid made an index grid)
const Prepared &prepared(const Source &src, int ring, bool index_grid = false) {
    static std::map<std::tuple<const Source *, int, bool>, std::unique_ptr<Prepared>> memo;
    std::unique_ptr<Prepared> &p = memo[{ &src, ring, index_grid }];
    if (!p) {
        p = std::make_unique<Prepared>();
        // (an index grid of a grid without leaves is 32 bytes larger)
        p->backend_bytes = size_t((src.bytes + 64 + 63) / 64 * 64);
        void *ptr = nullptr;
        REQUIRE(posix_memalign(&ptr, 64, p->backend_bytes) == 0);
        p->block.reset((uint32_t *) ptr);
        loader::PrepareOptions options;
        options.ring = ring;
        options.majorant_ring = std::max(ring, 1);
        options.index_grid = index_grid;
        p->grid = std::make_unique<loader::PreparedGrid>(loader::prepare_grid(
            loader::GridSource::memory("test_sampler", src.label, src.words.data(), src.bytes),
            p->block.get(), p->backend_bytes, options));
    }
    return *p;
}

/**
 * nanovdbvolume's load() and set_index_box() (src/volumes/grid_nanovdb.cpp)
 * for a grid in memory: prepare_grid into a 64-byte aligned block (memoized:
 * a copy of the block), the plugin's hand-off (set_up_sampler,
 * src/volumes/sampler_setup.h), set_box. `clamp`: wrap_mode "clamp";
 * `ring`: the ring in max() (the plugin's: 0 for nearest or clamp, 1 for
 * trilinear, 2 for tricubic). No
 * spectral rewrite (RGB variants).
 */
template <typename Float>
Loaded<Float> load(const Source &src, bool clamp, int ring, bool index_grid = false) {
    using HostBlock = typename ndr::GridSampler<Float>::HostBlock;
    Loaded<Float> l;
    ndr::GridSampler<Float> &s = l.sampler;

    const Prepared &p = prepared(src, ring, index_grid);
    const size_t backend_bytes = p.backend_bytes;
    void *ptr = nullptr;
    REQUIRE(posix_memalign(&ptr, 64, backend_bytes) == 0);
    HostBlock host((uint32_t *) ptr, std::free);
    std::memcpy(host.get(), p.block.get(), backend_bytes);
    const loader::PreparedGrid &g = *p.grid;
    const loader::GridSummary &summary = g.grid.summary();
    l.grid_type = summary.grid_type;
    l.max = g.max;
    for (int k = 0; k < 3; ++k)
        l.max3[k] = summary.grid_type == ndr::layout::GRID_TYPE_VEC3F ? g.max3[k] : g.max;

    // The reference reads these words: the grid after the loader's value policy
    l.words.assign(host.get(), host.get() + backend_bytes / 4);
    // (the memoized grid: set_up_sampler moves its spectral scales out, and
    // an RGB grid has none)
    nanovdb_mitsuba::set_up_sampler(s, *p.grid, std::move(host), backend_bytes / 4, clamp,
                                    std::nullopt);

    // set_index_box(): the active box, or the voxel at the origin if empty
    for (int k = 0; k < 3; ++k) {
        const int32_t lo = summary.empty ? 0 : summary.bbox_min[k],
                      hi = summary.empty ? 0 : summary.bbox_max[k];
        l.index_min[k] = lo;
        l.resolution[k] = int32_t(int64_t(hi) - int64_t(lo) + 1); // < 2^31 for the test grids
    }
    s.set_box(l.index_min, l.resolution, l.grid_type, clamp);
    return l;
}

// ---------------------------------------------------------------------------
//  The reference: PNanoVDB's reads, and the sampler's arithmetic written out
// ---------------------------------------------------------------------------

struct Reference {
    pnanovdb_buf_t buf;
    pnanovdb_root_handle_t root;
    pnanovdb_grid_type_t type;
    int32_t index_min[3], last[3];
    bool clamp;

    template <typename Float>
    Reference(const Loaded<Float> &l, bool clamp_) : type(l.grid_type), clamp(clamp_) {
        buf.data = const_cast<uint32_t *>(l.words.data());
        pnanovdb_grid_handle_t grid = { pnanovdb_address_null() };
        root = pnanovdb_tree_get_root(buf, pnanovdb_grid_get_tree(buf, grid));
        for (int k = 0; k < 3; ++k) {
            index_min[k] = l.index_min[k];
            last[k] = l.resolution[k] - 1;
        }
    }

    /// PNanoVDB's value at an absolute coordinate: the type's reader
    float value(const Coord3 &c) const {
        pnanovdb_coord_t ijk = { c[0], c[1], c[2] };
        pnanovdb_uint32_t level = 0;
        pnanovdb_address_t a =
            pnanovdb_root_get_value_address_and_level(type, buf, root, &ijk, &level);
        switch (type) {
            case PNANOVDB_GRID_TYPE_FLOAT: return pnanovdb_read_float(buf, a);
            case PNANOVDB_GRID_TYPE_FP4: return pnanovdb_root_fp4_read_float(buf, a, &ijk, level);
            case PNANOVDB_GRID_TYPE_FP8: return pnanovdb_root_fp8_read_float(buf, a, &ijk, level);
            case PNANOVDB_GRID_TYPE_FP16: return pnanovdb_root_fp16_read_float(buf, a, &ijk, level);
            case PNANOVDB_GRID_TYPE_FPN: return pnanovdb_root_fpn_read_float(buf, a, &ijk, level);
            case PNANOVDB_GRID_TYPE_HALF:
                return nvdb_test::f16c_to_float(uint16_t(pnanovdb_read_half(buf, a)));
            default: FAIL("not a scalar grid type: ", type); return 0.f;
        }
    }

    std::array<float, 3> value3(const Coord3 &c) const {
        pnanovdb_coord_t ijk = { c[0], c[1], c[2] };
        pnanovdb_address_t a = pnanovdb_root_get_value_address(type, buf, root, &ijk);
        return { pnanovdb_read_float(buf, a), pnanovdb_read_float(buf, pnanovdb_address_offset(a, 4)),
                 pnanovdb_read_float(buf, pnanovdb_address_offset(a, 8)) };
    }

    /// The absolute coordinate nearest() reads for a voxel relative to the box
    Coord3 nearest_coord(const Coord3 &voxel) const {
        Coord3 c;
        for (int k = 0; k < 3; ++k)
            c[k] = wrap_add(clamp ? std::min(std::max(voxel[k], 0), last[k]) : voxel[k],
                            index_min[k]);
        return c;
    }

    /// A trilinear stencil: corner 0's absolute coordinate and the 8 weights
    struct Stencil {
        Coord3 c0;
        float weight[8];
        Coord3 corner(int i) const {
            return { wrap_add(c0[0], i & 1), wrap_add(c0[1], (i >> 1) & 1),
                     wrap_add(c0[2], (i >> 2) & 1) };
        }
    };

    /// clamp_position, index_floor and the weights of sampler_impl.h
    Stencil stencil(const Pos3 &rel_) const {
        constexpr float limit = 2147483520.f;
        Stencil s;
        float w0[3], w1[3];
        for (int k = 0; k < 3; ++k) {
            const float rel = clamp ? std::min(std::max(rel_[k], 0.f), float(last[k]))
                                    : std::min(std::max(rel_[k], -limit), limit);
            const int32_t base = int32_t(std::floor(rel));
            w1[k] = rel - float(base);
            w0[k] = 1.f - w1[k];
            s.c0[k] = wrap_add(base, index_min[k]);
        }
        for (int i = 0; i < 8; ++i) {
            float w = 1.f;
            for (int k = 0; k < 3; ++k)
                w = w * (((i >> k) & 1) ? w1[k] : w0[k]);
            s.weight[i] = w;
        }
        return s;
    }

    float nearest(const Coord3 &voxel, float max) const {
        return std::min(value(nearest_coord(voxel)), max);
    }

    float trilinear(const Pos3 &rel, float max) const {
        const Stencil s = stencil(rel);
        float sum = 0.f;
        for (int i = 0; i < 8; ++i)
            sum = std::fmaf(value(s.corner(i)), s.weight[i], sum);
        return std::min(sum, max);
    }

    std::array<float, 3> nearest3(const Coord3 &voxel, const std::array<float, 3> &max3) const {
        std::array<float, 3> v = value3(nearest_coord(voxel));
        for (int k = 0; k < 3; ++k)
            v[k] = std::min(v[k], max3[k]);
        return v;
    }

    std::array<float, 3> trilinear3(const Pos3 &rel, const std::array<float, 3> &max3) const {
        const Stencil s = stencil(rel);
        std::array<float, 3> sum = { 0.f, 0.f, 0.f };
        for (int i = 0; i < 8; ++i) {
            const std::array<float, 3> v = value3(s.corner(i));
            for (int k = 0; k < 3; ++k)
                sum[k] = std::fmaf(v[k], s.weight[i], sum[k]);
        }
        for (int k = 0; k < 3; ++k)
            sum[k] = std::min(sum[k], max3[k]);
        return sum;
    }
};

// ---------------------------------------------------------------------------
//  Queries, relative to a grid's box
// ---------------------------------------------------------------------------

struct Queries {
    std::vector<Coord3> voxels;    ///< for nearest
    std::vector<Pos3> positions;   ///< for trilinear
};

/**
 * The grid's query coordinates relative to its box (active voxels, tiles,
 * the box grown by 16, far points, node boundaries) with a random fraction
 * added for trilinear (a stencil at a boundary coordinate straddles the leaf
 * or node), plus the positions around the box's edges on every axis, where
 * clamping matters.
 */
template <typename Float> Queries make_queries(const Source &src, const Loaded<Float> &l) {
    Queries q;
    nvdb_testdata::Rng rng = nvdb_testdata::Rng::counter(src.words.size());
    for (const Coord3 &c : src.coords) {
        Coord3 v;
        Pos3 p;
        const int kind = int(rng.below(8)); // 1 in 8: integer positions
        for (int k = 0; k < 3; ++k) {
            v[k] = wrap_sub(c[k], l.index_min[k]);
            const double frac = kind == 0 ? 0.0 : rng.uniform();
            p[k] = float(double(v[k]) + frac);
        }
        q.voxels.push_back(v);
        q.positions.push_back(p);
    }
    for (int i = 0; i < 7 * 7 * 7; ++i) {
        Coord3 v;
        Pos3 p;
        for (int k = 0, j = i; k < 3; ++k, j /= 7) {
            const float last = float(l.resolution[k] - 1);
            const float at[7] = { -1.5f, -0.5f, 0.f, 0.25f, last - 0.25f, last + 0.5f, last + 1.5f };
            const int32_t vat[7] = { -2, -1, 0, 1, l.resolution[k] - 1, l.resolution[k],
                                     l.resolution[k] + 1 };
            p[k] = at[j % 7];
            v[k] = vat[j % 7];
        }
        q.voxels.push_back(v);
        q.positions.push_back(p);
    }
    return q;
}

// ---------------------------------------------------------------------------
//  Running the sampler on a backend
// ---------------------------------------------------------------------------

/// A JIT array's n values on the host (a literal is broadcast)
template <typename T> std::vector<dr::scalar_t<T>> to_host(const T &a, size_t n) {
    using Detached = dr::detached_t<T>;
    Detached d = dr::detach<false>(a);
    if (dr::width(d) != n)
        d = d + dr::zeros<Detached>(n);
    dr::eval(d);
    std::vector<dr::scalar_t<T>> out(n);
    dr::store(out.data(), d);
    return out;
}

/// `active` as the backend's mask: loaded, never a literal, so that the
/// JIT cannot fold masked reads away
template <typename Float> dr::mask_t<Float> jit_mask(const std::vector<uint8_t> &active) {
    using UInt32 = dr::uint32_array_t<Float>;
    std::vector<uint32_t> a(active.begin(), active.end());
    return dr::load<UInt32>(a.data(), a.size()) != 0u;
}

template <typename T, typename S>
dr::Array<T, 3> jit_vector(const std::vector<std::array<S, 3>> &v) {
    std::vector<S> c[3];
    for (const auto &x : v)
        for (int k = 0; k < 3; ++k)
            c[k].push_back(x[k]);
    return { dr::load<T>(c[0].data(), v.size()), dr::load<T>(c[1].data(), v.size()),
             dr::load<T>(c[2].data(), v.size()) };
}

/// What a lookup returns per query: 1 or 3 channels, in `out[channels * i + k]`
enum class Lookup { Nearest, Trilinear, Nearest3, Trilinear3 };

std::string lookup_name(Lookup l) {
    switch (l) {
        case Lookup::Nearest: return "nearest";
        case Lookup::Trilinear: return "trilinear";
        case Lookup::Nearest3: return "nearest3";
        default: return "trilinear3";
    }
}

int channels_of(Lookup l) { return l == Lookup::Nearest || l == Lookup::Trilinear ? 1 : 3; }

/// The sampler's lookups of every query (lanes where `active` is 0 are masked off)
template <typename Float>
std::vector<float> run(const ndr::GridSampler<Float> &s, Lookup lookup, const Queries &q,
                       const std::vector<uint8_t> &active) {
    const size_t n = q.voxels.size();
    const int ch = channels_of(lookup);
    std::vector<float> out(ch * n);
    if constexpr (!dr::is_jit_v<Float>) {
        using V3i = dr::Array<int32_t, 3>;
        using V3f = dr::Array<float, 3>;
        for (size_t i = 0; i < n; ++i) {
            const V3i v(q.voxels[i][0], q.voxels[i][1], q.voxels[i][2]);
            const V3f p(q.positions[i][0], q.positions[i][1], q.positions[i][2]);
            const bool a = active[i] != 0;
            switch (lookup) {
                case Lookup::Nearest: out[i] = s.nearest(v, a); break;
                case Lookup::Trilinear: out[i] = s.trilinear(p, a); break;
                default: {
                    const V3f r = lookup == Lookup::Nearest3 ? s.nearest3(v, a) : s.trilinear3(p, a);
                    for (int k = 0; k < 3; ++k)
                        out[3 * i + k] = r[k];
                }
            }
        }
    } else {
        using Int32 = dr::int32_array_t<Float>;
        const dr::mask_t<Float> a = jit_mask<Float>(active);
        const dr::Array<Int32, 3> v = jit_vector<Int32>(q.voxels);
        const dr::Array<Float, 3> p = jit_vector<Float>(q.positions);
        if (ch == 1) {
            const Float r = lookup == Lookup::Nearest ? s.nearest(v, a) : s.trilinear(p, a);
            out = to_host(r, n);
        } else {
            const dr::Array<Float, 3> r =
                lookup == Lookup::Nearest3 ? s.nearest3(v, a) : s.trilinear3(p, a);
            for (int k = 0; k < 3; ++k) {
                const std::vector<float> c = to_host(r[k], n);
                for (size_t i = 0; i < n; ++i)
                    out[3 * i + k] = c[i];
            }
        }
    }
    return out;
}

/// The reference of one query: 1 or 3 channels
std::array<float, 3> reference(const Reference &ref, Lookup lookup, const Queries &q, size_t i,
                               float max, const std::array<float, 3> &max3) {
    switch (lookup) {
        case Lookup::Nearest: return { ref.nearest(q.voxels[i], max), 0.f, 0.f };
        case Lookup::Trilinear: return { ref.trilinear(q.positions[i], max), 0.f, 0.f };
        case Lookup::Nearest3: return ref.nearest3(q.voxels[i], max3);
        default: return ref.trilinear3(q.positions[i], max3);
    }
}

/// The smallest and largest corner of a trilinear stencil, per channel
std::array<std::array<float, 3>, 2> corner_range(const Reference &ref, const Pos3 &p, int ch) {
    const Reference::Stencil st = ref.stencil(p);
    std::array<std::array<float, 3>, 2> r;
    r[0].fill(INFINITY);
    r[1].fill(-INFINITY);
    for (int i = 0; i < 8; ++i) {
        std::array<float, 3> v = ch == 1 ? std::array<float, 3>{ ref.value(st.corner(i)), 0.f, 0.f }
                                         : ref.value3(st.corner(i));
        for (int k = 0; k < ch; ++k) {
            r[0][k] = std::min(r[0][k], v[k]);
            r[1][k] = std::max(r[1][k], v[k]);
        }
    }
    return r;
}

template <typename Float> std::string backend_name() {
    if constexpr (!dr::is_jit_v<Float>)
        return "scalar";
    else if constexpr (dr::backend_v<Float> == JitBackend::LLVM)
        return "LLVM";
    else
        return "CUDA";
}

struct Outcome {
    size_t mismatches = 0, clamped = 0, lanes = 0;
    size_t off_corners = 0;
};

/// The sampler's lookups against the reference, bit for bit; inactive lanes
/// must be 0. `clamped`: active lookups the reference clamped to max.
/// Trilinear lookups are also checked against a property that does not
/// mirror the arithmetic: they lie between the smallest and the largest of
/// their 8 corners (each clamped to max), up to 4 ulps of the largest
/// corner magnitude (weights rounded to floats and summed; sampler_impl.h
/// measured 3 ulps), positions beyond +-2147483520 (kept at that edge)
/// included: unclipped, a weight there reached 128 and a lookup -128.
template <typename Float>
Outcome compare(const std::string &label, const ndr::GridSampler<Float> &s,
                const Reference &ref, Lookup lookup, const Queries &q,
                const std::vector<uint8_t> &active, float max,
                const std::array<float, 3> &max3) {
    const std::vector<float> got = run(s, lookup, q, active);
    const int ch = channels_of(lookup);
    const bool trilinear = lookup == Lookup::Trilinear || lookup == Lookup::Trilinear3;
    Outcome o;
    for (size_t i = 0; i < q.voxels.size(); ++i) {
        const bool a = active[i] != 0;
        o.lanes += a;
        const std::array<float, 3> expect =
            a ? reference(ref, lookup, q, i, max, max3) : std::array<float, 3>{ 0.f, 0.f, 0.f };
        bool clamped = false;
        for (int k = 0; k < ch; ++k) {
            const float value = got[ch * i + k];
            const float bound = ch == 1 ? max : max3[k];
            clamped |= a && expect[k] == bound;
            if (bits_of(value) != bits_of(expect[k]) && ++o.mismatches <= 5) {
                const Coord3 &v = q.voxels[i];
                const Pos3 &p = q.positions[i];
                INFO(backend_name<Float>(), " ", lookup_name(lookup), ", ", label, ", clamp ",
                     ref.clamp, ", channel ", k, ", active ", a, ", voxel (", v[0], ", ", v[1],
                     ", ", v[2], "), position (", p[0], ", ", p[1], ", ", p[2], ")");
                CHECK(value == expect[k]);
            }
        }
        o.clamped += clamped;
        if (trilinear && a) {
            const auto range = corner_range(ref, q.positions[i], ch);
            int off = -1; // the first channel outside its corners
            for (int k = ch - 1; k >= 0; --k) {
                const float bound = ch == 1 ? max : max3[k];
                const float lo = std::min(range[0][k], bound), hi = std::min(range[1][k], bound);
                const float slack = 4.f * FLT_EPSILON *
                                    std::max(std::fabs(range[0][k]), std::fabs(range[1][k]));
                if (!(got[ch * i + k] >= lo - slack && got[ch * i + k] <= hi + slack))
                    off = k;
            }
            o.off_corners += off >= 0;
            if (off >= 0 && o.off_corners <= 5) {
                const Pos3 &p = q.positions[i];
                INFO(backend_name<Float>(), " ", lookup_name(lookup), ", ", label, ", clamp ",
                     ref.clamp, ", position (", p[0], ", ", p[1], ", ", p[2], "), channel ", off,
                     ": ", got[ch * i + off], " outside its corners [", range[0][off], ", ",
                     range[1][off], "] (clamped to ", ch == 1 ? max : max3[off], ")");
                CHECK(off < 0);
            }
        }
    }
    return o;
}

std::vector<uint8_t> all_active(size_t n) { return std::vector<uint8_t>(n, 1); }

/// 1 lane in 3 masked off (deterministic)
std::vector<uint8_t> some_active(size_t n, uint64_t seed) {
    nvdb_testdata::Rng rng = nvdb_testdata::Rng::counter(seed);
    std::vector<uint8_t> a(n);
    for (auto &x : a)
        x = rng.below(3) != 0;
    return a;
}

/// Checks 1 and 2: nearest and trilinear equal the reference on every
/// scalar source, with and without clamping to the box
template <typename Float> void check_scalar_lookups() {
    init_backend<Float>();
    for (const Source &src : scalar_sources()) {
        SUBCASE(src.label.c_str()) {
            for (bool clamp : { false, true }) {
                Loaded<Float> l = load<Float>(src, clamp, !clamp);
                const Reference ref(l, clamp);
                const Queries q = make_queries(src, l);
                const std::vector<uint8_t> active = all_active(q.voxels.size());
                // Stencils that cross a leaf (8^3) or a lower node (128^3)
                size_t leaf_cross = 0, lower_cross = 0;
                for (const Pos3 &p : q.positions) {
                    const Reference::Stencil st = ref.stencil(p);
                    bool leaf = false, lower = false;
                    for (int k = 0; k < 3; ++k) {
                        leaf |= (st.c0[k] & 7) == 7;
                        lower |= (st.c0[k] & 127) == 127;
                    }
                    leaf_cross += leaf;
                    lower_cross += lower;
                }
                for (Lookup lookup : { Lookup::Nearest, Lookup::Trilinear }) {
                    const Outcome o = compare(src.label, l.sampler, ref, lookup, q, active,
                                              l.max, l.max3);
                    MESSAGE(backend_name<Float>(), " ", lookup_name(lookup), ", ", src.label,
                            ", clamp ", clamp, ": ", o.lanes - o.mismatches, " of ", o.lanes,
                            " identical to PNanoVDB (", o.clamped, " at max = ", l.max,
                            "); stencils crossing a leaf ", leaf_cross, ", a lower node ",
                            lower_cross, "; off corners ", o.off_corners);
                    CHECK(o.mismatches == 0);
                    CHECK(o.off_corners == 0);
                }
                CHECK(q.voxels.size() >= QUERY_COUNT);
                if (src.label.rfind("empty", 0) != 0 && !clamp) {
                    CHECK(leaf_cross > q.positions.size() / 100);
                    CHECK(lower_cross > 0);
                }
            }
        }
    }
}

/// Index grids (differentiable=true): every scalar source made an index
/// grid reads as the grid itself, lane for lane and bit for bit (the grid's
/// lookups are checked against PNanoVDB above)
template <typename Float> void check_index_lookups() {
    init_backend<Float>();
    for (const Source &src : scalar_sources()) {
        SUBCASE(src.label.c_str()) {
            for (bool clamp : { false, true }) {
                Loaded<Float> grid = load<Float>(src, clamp, !clamp),
                              index = load<Float>(src, clamp, !clamp, true);
                CHECK(index.grid_type == ndr::layout::GRID_TYPE_ONINDEX);
                CHECK(index.max == grid.max);
                const loader::PreparedGrid &pg = *prepared(src, !clamp, true).grid;
                bool inactive_differ = false;
                for (const std::string &w : pg.warnings)
                    inactive_differ |= w.find("inactive voxels hold values") != std::string::npos;
                const Queries q = make_queries(src, grid);
                const std::vector<uint8_t> active = some_active(q.voxels.size(), 77);
                for (Lookup lookup : { Lookup::Nearest, Lookup::Trilinear }) {
                    const std::vector<float> a = run(grid.sampler, lookup, q, active),
                                             b = run(index.sampler, lookup, q, active);
                    size_t differ = 0;
                    for (size_t i = 0; i < a.size(); ++i)
                        differ += std::memcmp(&a[i], &b[i], 4) != 0;
                    MESSAGE(backend_name<Float>(), " ", lookup_name(lookup), ", ", src.label,
                            " as an index grid (", pg.index_values.size(), " values), clamp ",
                            clamp, ": ", a.size() - differ, " of ", a.size(), " lanes equal",
                            std::string(inactive_differ ? " (inactive voxels differ from the background)" : ""));
                    if (!inactive_differ)
                        CHECK(differ == 0);
                }
            }
        }
    }
}

} // namespace

// ---------------------------------------------------------------------------

TEST_CASE_TEMPLATE("index grids (differentiable=true) read as their grids", Float, float,
                   LLVMFloat) {
    check_index_lookups<Float>();
}

TEST_CASE_TEMPLATE("nearest and trilinear equal PNanoVDB's reads (float, half, fp8, fpn)", Float,
                   float, LLVMFloat) {
    check_scalar_lookups<Float>();
}

TEST_CASE("CUDA: nearest and trilinear equal PNanoVDB's reads" * NVDB_CUDA_CASE_SKIP) {
#if NVDB_TEST_CUDA
    check_scalar_lookups<CUDAFloat>();
#endif
}

TEST_CASE_TEMPLATE("every lookup is clamped to max()", Float, float, LLVMFloat) {
    init_backend<Float>();
    for (const Source &src : scalar_sources()) {
        if (src.label.rfind("empty", 0) == 0)
            continue; // one value everywhere: nothing to clamp below it
        SUBCASE(src.label.c_str()) {
            Loaded<Float> l = load<Float>(src, false, true);
            const Reference ref(l, false);
            const Queries q = make_queries(src, l);
            const std::vector<uint8_t> active = all_active(q.voxels.size());
            // A bound below the values: half the largest value nearest() reads
            // in the queries (or, where those are all <= 0, a negative one)
            float largest = -INFINITY;
            for (const Coord3 &v : q.voxels)
                largest = std::max(largest, ref.nearest(v, INFINITY));
            const float max = largest > 0.f ? largest * 0.5f : largest - 1.f;
            const float max3[3] = { max, max, max };
            l.sampler.set_bounds(max, max3);
            for (Lookup lookup : { Lookup::Nearest, Lookup::Trilinear }) {
                const Outcome o = compare(src.label, l.sampler, ref, lookup, q, active, max,
                                          { max, max, max });
                MESSAGE(backend_name<Float>(), " ", lookup_name(lookup), ", ", src.label,
                        ": max = ", max, ", ", o.clamped, " of ", o.lanes, " lookups clamped");
                CHECK(o.mismatches == 0);
                CHECK(o.off_corners == 0);
                CHECK(o.clamped > 0);
            }
        }
    }
}

TEST_CASE_TEMPLATE("Vec3f: nearest3 and trilinear3 equal PNanoVDB's reads, each channel clamped "
                   "to its max", Float, float, LLVMFloat) {
    init_backend<Float>();
    for (const Source &src : vec3_sources()) {
        SUBCASE(src.label.c_str()) {
            for (bool clamp : { false, true }) {
                Loaded<Float> l = load<Float>(src, clamp, !clamp);
                const Reference ref(l, clamp);
                const Queries q = make_queries(src, l);
                const std::vector<uint8_t> active = all_active(q.voxels.size());
                // The loader's max per channel, then lower ones, a different
                // fraction of each channel's
                for (bool lowered : { false, true }) {
                    std::array<float, 3> max3 = l.max3;
                    if (lowered) {
                        const float f[3] = { 0.5f, 0.75f, 0.25f };
                        for (int k = 0; k < 3; ++k)
                            max3[k] = l.max3[k] * f[k];
                        l.sampler.set_bounds(l.max, max3.data());
                    }
                    for (Lookup lookup : { Lookup::Nearest3, Lookup::Trilinear3 }) {
                        const Outcome o = compare(src.label, l.sampler, ref, lookup, q, active,
                                                  l.max, max3);
                        MESSAGE(backend_name<Float>(), " ", lookup_name(lookup), ", ",
                                src.label, ", clamp ", clamp, ", max3 = (", max3[0], ", ",
                                max3[1], ", ", max3[2], "): ", o.lanes - o.mismatches, " of ",
                                o.lanes, " identical, ", o.clamped, " with a channel at its max");
                        CHECK(o.mismatches == 0);
                        CHECK(o.off_corners == 0);
                        if (lowered)
                            CHECK(o.clamped > 0);
                    }
                }
            }
        }
    }
}

TEST_CASE_TEMPLATE("counters count the active lanes of every lookup; inactive lanes return 0",
                   Float, float, LLVMFloat) {
    init_backend<Float>();
    using Counter = ndr::Counter;
    const Source &src = source("noisy_cloud"), &src3 = source("noisy_cloud (vec3f)");
    Loaded<Float> l = load<Float>(src, false, true);
    Loaded<Float> l3 = load<Float>(src3, false, true);
    const Reference ref(l, false), ref3(l3, false);
    const Queries q = make_queries(src, l), q3 = make_queries(src3, l3);

    // Before enable_counters: nothing counted, all zeros
    CHECK_FALSE(l.sampler.counting());
    run(l.sampler, Lookup::Nearest, q, all_active(q.voxels.size()));
    for (uint64_t c : l.sampler.counter_values())
        CHECK(c == 0);

    l.sampler.enable_counters();
    l3.sampler.enable_counters();
    CHECK(l.sampler.counting());
    uint64_t expect = 0, expect3 = 0;
    uint64_t seed = 1;
    for (Lookup lookup : { Lookup::Nearest, Lookup::Trilinear }) {
        const std::vector<uint8_t> active = some_active(q.voxels.size(), seed++);
        const Outcome o = compare(src.label, l.sampler, ref, lookup, q, active, l.max, l.max3);
        CHECK(o.mismatches == 0); // the active lanes as the reference, the others 0
        CHECK(o.lanes < q.voxels.size());
        expect += o.lanes;
    }
    for (Lookup lookup : { Lookup::Nearest3, Lookup::Trilinear3 }) {
        const std::vector<uint8_t> active = some_active(q3.voxels.size(), seed++);
        const Outcome o = compare(src3.label, l3.sampler, ref3, lookup, q3, active, l3.max, l3.max3);
        CHECK(o.mismatches == 0);
        expect3 += o.lanes;
    }
    // All lanes off: nothing counted
    run(l.sampler, Lookup::Trilinear, q, std::vector<uint8_t>(q.voxels.size(), 0));

    const std::vector<uint64_t> c = l.sampler.counter_values(), c3 = l3.sampler.counter_values();
    REQUIRE(c.size() == (size_t) Counter::Count);
    MESSAGE(backend_name<Float>(), ": ", c[(uint32_t) Counter::Lookup], " lookups counted of ",
            expect, " active lanes; Vec3f ", c3[(uint32_t) Counter::Lookup], " of ", expect3);
    CHECK(c[(uint32_t) Counter::Lookup] == expect);
    CHECK(c3[(uint32_t) Counter::Lookup] == expect3);
    // No walk was run: its counters stay 0
    for (uint32_t i = 1; i < (uint32_t) Counter::Count; ++i) {
        INFO("counter ", ndr::COUNTER_NAMES[i]);
        CHECK(c[i] == 0);
        CHECK(c3[i] == 0);
    }
}

TEST_CASE_TEMPLATE("inactive lanes read nothing: a grid of PROT_NONE memory behind a false mask",
                   Float, float, LLVMFloat) {
    init_backend<Float>();
    using HostBlock = typename ndr::GridSampler<Float>::HostBlock;
    using UInt32 = dr::uint32_array_t<Float>;
    // Every word a 32-bit address can reach faults (tests/guarded_buffer.h)
    nvdb_test::GuardedBuffer guard(0);
    for (const Source *src : { &source("noisy_cloud"), &source("noisy_cloud (vec3f)") }) {
        CAPTURE(src->label);
        {
            Loaded<Float> l = load<Float>(*src, false, true);
            const Queries q = make_queries(*src, l);
            const size_t words = l.words.size();
            // The reader plan (root, root index) stays: it is the grid's
            if constexpr (dr::is_jit_v<Float>) {
                static_assert(dr::backend_v<Float> == JitBackend::LLVM);
                l.sampler.grid = UInt32::steal(jit_var_mem_map(
                    JitBackend::LLVM, VarType::UInt32, guard.data(), words, 0));
            } else {
                (void) words;
                l.sampler.grid = HostBlock((uint32_t *) guard.data(), +[](void *) {});
            }
            l.sampler.enable_counters();
            const std::vector<uint8_t> none(q.voxels.size(), 0);
            const bool vec3 = l.grid_type == ndr::layout::GRID_TYPE_VEC3F;
            for (Lookup lookup : vec3 ? std::vector<Lookup>{ Lookup::Nearest3, Lookup::Trilinear3 }
                                      : std::vector<Lookup>{ Lookup::Nearest, Lookup::Trilinear }) {
                const std::vector<float> got = run(l.sampler, lookup, q, none);
                size_t nonzero = 0;
                for (float v : got)
                    nonzero += bits_of(v) != 0;
                INFO(lookup_name(lookup));
                CHECK(nonzero == 0);
            }
            CHECK(l.sampler.counter_values()[(uint32_t) ndr::Counter::Lookup] == 0);
            if constexpr (dr::is_jit_v<Float>)
                dr::sync_thread(); // the mapping outlives every kernel that saw it
        }
    }
}

// ---------------------------------------------------------------------------
//  Stochastic filters
// ---------------------------------------------------------------------------

namespace {

/// The uniform cubic B-spline's weights at t in [0, 1): taps -1, 0, 1, 2
std::array<double, 4> bspline(double t) {
    const double s = 1.0 - t;
    return { s * s * s / 6.0, (3 * t * t * t - 6 * t * t + 4) / 6.0,
             (-3 * t * t * t + 3 * t * t + 3 * t + 1) / 6.0, t * t * t / 6.0 };
}

/// A position as clamp_position keeps it: in the box (clamp), or within
/// the int32 range
float kept_position(const Reference &ref, float rel, int k) {
    return ref.clamp ? std::min(std::max(rel, 0.f), float(ref.last[k]))
                     : std::min(std::max(rel, -ndr::INDEX_LIMIT), ndr::INDEX_LIMIT);
}

/// The deterministic filters the stochastic ones estimate, from PNanoVDB's
/// reads: trilinear (the reference's, unclamped to max: its corners are), or
/// tricubic (64 taps with B-spline weights; taps clamped as nearest() does)
double filtered(const Reference &ref, const Pos3 &rel_, bool tricubic, float max) {
    if (!tricubic)
        return ref.trilinear(rel_, max);
    double w[3][4];
    Coord3 base;
    for (int k = 0; k < 3; ++k) {
        const float rel = kept_position(ref, rel_[k], k);
        base[k] = int32_t(std::floor(rel));
        const std::array<double, 4> b = bspline(double(rel) - base[k]);
        std::copy(b.begin(), b.end(), w[k]);
    }
    double sum = 0.0;
    for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j)
            for (int l = 0; l < 4; ++l)
                sum += w[0][i] * w[1][j] * w[2][l] *
                       ref.nearest({ base[0] - 1 + i, base[1] - 1 + j, base[2] - 1 + l }, max);
    return sum;
}

} // namespace

TEST_CASE_TEMPLATE("stochastic filters: one voxel in reach, whose mean over the offsets is the "
                   "trilinear (tricubic) value", Float, float, LLVMFloat) {
    init_backend<Float>();
    using Int32 = dr::int32_array_t<Float>;
    using V3f = dr::Array<Float, 3>;
    constexpr size_t POINTS = 48, DRAWS = 4096;
    for (const char *label : { "noisy_cloud", "noisy_cloud (fp8)", "lower_tiles",
                               "nonzero_background" })
        for (bool tricubic : { false, true })
            for (bool clamp : { false, true }) {
                const Source &src = source(label);
                Loaded<Float> l = load<Float>(src, clamp, clamp ? 0 : tricubic ? 2 : 1);
                const Reference ref(l, clamp);
                const Queries q = make_queries(src, l);
                nvdb_testdata::Rng rng = nvdb_testdata::Rng::counter(77 + tricubic + 2 * clamp);
                size_t out_of_reach = 0, off = 0, checked = 0;
                double worst_z = 0.0;
                for (size_t i = 0; i < POINTS; ++i) {
                    const Pos3 &p = q.positions[(i * 7919) % q.positions.size()];
                    std::vector<float> u[3];
                    for (int k = 0; k < 3; ++k)
                        for (size_t d = 0; d < DRAWS; ++d)
                            u[k].push_back(float(rng.uniform()));
                    // The voxels picked and their values
                    std::vector<int32_t> voxel[3];
                    std::vector<float> value;
                    if constexpr (!dr::is_jit_v<Float>) {
                        for (size_t d = 0; d < DRAWS; ++d) {
                            const dr::Array<int32_t, 3> v = l.sampler.stochastic_voxel(
                                V3f(p[0], p[1], p[2]), V3f(u[0][d], u[1][d], u[2][d]), tricubic);
                            for (int k = 0; k < 3; ++k)
                                voxel[k].push_back(v[k]);
                            value.push_back(l.sampler.nearest(v, true));
                        }
                    } else {
                        // (opaque: the point is no literal, so all points share a kernel)
                        V3f rel(dr::opaque<Float>(p[0], DRAWS), dr::opaque<Float>(p[1], DRAWS),
                                dr::opaque<Float>(p[2], DRAWS)),
                            uu(dr::load<Float>(u[0].data(), DRAWS), dr::load<Float>(u[1].data(), DRAWS),
                               dr::load<Float>(u[2].data(), DRAWS));
                        const dr::Array<Int32, 3> v = l.sampler.stochastic_voxel(rel, uu, tricubic);
                        for (int k = 0; k < 3; ++k)
                            voxel[k] = to_host(v[k], DRAWS);
                        value = to_host(l.sampler.nearest(v, true), DRAWS);
                    }
                    // Reach: [b, b + 1] (trilinear), [b - 1, b + 2] (tricubic) per axis
                    for (size_t d = 0; d < DRAWS; ++d)
                        for (int k = 0; k < 3; ++k) {
                            const float rel = kept_position(ref, p[k], k);
                            const int32_t b = int32_t(std::floor(rel)), lo = tricubic ? b - 1 : b,
                                          hi = tricubic ? b + 2 : b + 1;
                            out_of_reach += voxel[k][d] < lo || voxel[k][d] > hi;
                        }
                    // The mean against the deterministic filter
                    double mean = 0.0, sq = 0.0;
                    for (float x : value) {
                        mean += x;
                        sq += double(x) * x;
                    }
                    mean /= DRAWS;
                    const double var = std::max(sq / DRAWS - mean * mean, 0.0),
                                 se = std::sqrt(var / DRAWS),
                                 expected = filtered(ref, p, tricubic, l.max),
                                 err = std::abs(mean - expected),
                                 tol = 5.0 * se + 1e-5 * std::max(1.0, std::abs(expected));
                    if (se > 0.0)
                        worst_z = std::max(worst_z, err / se);
                    off += err > tol;
                    ++checked;
                }
                MESSAGE(backend_name<Float>(), " ", std::string(tricubic ? "tricubic" : "trilinear"),
                        std::string(clamp ? " (clamp) " : " "), std::string(label), ": ", checked,
                        " points x ", DRAWS,
                        " draws, worst |z| = ", worst_z);
                CHECK(out_of_reach == 0);
                CHECK(off == 0);
            }
}
