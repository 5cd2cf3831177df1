/*
    The majorant walk (include/nanovdb_drjit/majorant_walk.h) on random rays
    through the test grids:

      - its segments tile [tmin, tmax] without gaps or overlaps;
      - the bound of every segment covers every value a lookup reads at a
        point of it: at 10^6 points per grid, the voxel a nearest lookup
        reads and the 8 corners of the trilinear stencil, read by PNanoVDB's
        C code (the independent reference), are all at most the bound;
      - with coarse_limit = 0 every segment's bound is the bound of the
        finest cell at its midpoint, found through NanoVDB's own node structs
        and the loader's majorant table (a walk done by hand); thin nodes
        (coarse_limit > 0) are crossed as one cell with the node's M;
      - empty root space is crossed in one step (walk_far: far_coords, whose
        root tiles lie 10^9 voxels apart, walks in a few steps per ray);
      - the LLVM walk equals the scalar walk bit for bit, step for step, and
        the faithful readers (PNanoVDB's root search, 64-bit child offsets)
        walk exactly as the plan's fast readers;
      - majorants with a ring of 2 voxels (the plugin's, for the stochastic
        tricubic filter) cover the 64 taps of a cubic B-spline stencil at
        every point, and the default ring of 1 does not (some tap exceeds it
        on the noisy grids: the wider ring is needed);
      - the same on Fp8, FpN, Half and Vec3f versions of four grids
        (tests/typed_grids.h), read by PNanoVDB's per-type readers (the
        hand walk, written against NanoVDB's float node structs, is left out
        there);
      - the same on index grids (OnIndex) made from four grids, whose values
        were then changed as an optimizer step changes them (scaled at
        random, and one raised 100x above the old maximum) and their
        majorants recomputed as the plugin's parameters_changed does: read
        through the index grid's lookups (tests/test_sampler.cpp checks
        those against NanoVDB's accessor).
*/

#define PNANOVDB_C
#define PNANOVDB_ADDRESS_64
#include <nanovdb/PNanoVDB.h>

#include <nanovdb_drjit/fast_readers.h>
#include <nanovdb_drjit/majorant_rebuild.h>
#include <nanovdb_drjit/majorant_walk.h>
#include <nanovdb_loader/index_grid.h>
#include <nanovdb_loader/majorants.h>
#include <nanovdb_loader/reader_policy.h>
#include <nanovdb_loader/validation.h>
#include <drjit/jit.h>
#include <drjit-core/jit.h>

#include <doctest/doctest.h>
#include <grids.h>
#include <hand_walk.h>
#include <typed_grids.h>

#include <nanovdb/util/OpenToNanoVDB.h>

#include <cmath>
#include <cstring>
#include <map>
#include <random>
#include <vector>

namespace ndr = nanovdb_drjit;
namespace loader = nanovdb_loader;
namespace dr = drjit;

namespace {

constexpr size_t RAY_COUNT = 4000;
constexpr size_t POINTS_PER_GRID = 1000000;
constexpr int MAX_STEPS = 400;

using Handle = nanovdb::GridHandle<nanovdb::HostBuffer>;

struct WalkGrid {
    std::string name;
    uint32_t grid_type = 1;  ///< NanoVDB's GridType; typed (not 1): no hand walk
    Handle handle;
    std::vector<uint32_t> words;
    loader::ReaderPlan plan;
    loader::NodeMajorants majorants;
    int32_t base[3];
    int32_t lo[3], hi[3]; ///< the index box rays aim at
    std::vector<float> index_values; ///< index grids: the values
    float index_background = 0.f;
};

/// The plan, the majorants and the box of a validated grid
void set_up_walk_grid(WalkGrid &g, const loader::ValidatedGrid &v) {
    g.plan = loader::plan_readers(v);
    g.majorants = loader::node_majorants(v);
    const loader::GridSummary &s = v.summary();
    for (int a = 0; a < 3; ++a) {
        g.lo[a] = s.empty ? 0 : s.bbox_min[a];
        g.hi[a] = s.empty ? 0 : s.bbox_max[a];
        g.base[a] = int32_t(uint32_t(g.lo[a]) & ~4095u);
    }
}

WalkGrid make_walk_grid(const std::string &name, Handle handle,
                        const nvdb_test::TypedGrid *typed = nullptr) {
    WalkGrid g;
    g.name = name;
    uint64_t bytes = handle.size();
    if (typed) {
        g.name += " (" + typed->type + ")";
        g.grid_type = typed->grid_type;
        g.words = typed->words;
        bytes = typed->bytes;
    } else {
        g.words.resize((handle.size() + 3) / 4);
        std::memcpy(g.words.data(), handle.data(), handle.size());
    }
    g.handle = std::move(handle);
    set_up_walk_grid(g, loader::validate_grid(g.name, g.words.data(), bytes));
    return g;
}

/// `handle` made an index grid, its values then changed as an optimizer
/// step might (each scaled by a random factor in [0, 3), one raised to 100x
/// the old maximum), and its majorants computed from the new values (as
/// the plugin's parameters_changed computes them)
WalkGrid make_index_walk_grid(const std::string &name, Handle handle) {
    std::vector<uint32_t> words((handle.size() + 3) / 4);
    std::memcpy(words.data(), handle.data(), handle.size());
    loader::ValidatedGrid v = loader::validate_grid(name, words.data(), handle.size());
    loader::MadeIndexGrid made = loader::make_index_grid(v);
    WalkGrid g;
    g.name = name + " (index grid, updated)";
    g.grid_type = ndr::layout::GRID_TYPE_ONINDEX;
    g.words.resize((made.bytes.size() + 3) / 4);
    std::memcpy(g.words.data(), made.bytes.data(), made.bytes.size());
    g.index_values = std::move(made.values.values);
    g.index_background = made.values.background[0];
    std::mt19937_64 rng(23);
    std::uniform_real_distribution<float> u(0.f, 3.f);
    float old_max = 0.f;
    for (float &x : g.index_values) {
        old_max = std::max(old_max, x);
        x *= u(rng);
    }
    if (!g.index_values.empty())
        g.index_values[g.index_values.size() / 2] = 100.f * std::max(old_max, 1.f);
    g.handle = std::move(handle);
    set_up_walk_grid(g, loader::validate_grid(g.name, g.words.data(), made.bytes.size(),
                                              loader::IndexValues{ g.index_values.data(),
                                                                   g.index_values.size(),
                                                                   { g.index_background,
                                                                     g.index_background,
                                                                     g.index_background } }));
    return g;
}

/// A tile grid with values at every level and a lower node that is thin
Handle mixed_tiles() {
    openvdb::initialize();
    auto g = openvdb::FloatGrid::create(0.f);
    auto &tree = g->tree();
    tree.addTile(1, openvdb::Coord(8, 0, 0), 7.0f, true);     // lower tile
    tree.addTile(2, openvdb::Coord(128, 0, 0), 0.5f, true);   // upper tile
    tree.addTile(3, openvdb::Coord(4096, 0, 0), 2.0f, true);  // root tile
    tree.setValue(openvdb::Coord(1, 2, 3), 3.0f);
    tree.setValue(openvdb::Coord(7, 7, 7), 11.0f);            // next to the lower tile
    tree.setValue(openvdb::Coord(-1, -1, -1), 0.25f);
    for (int i = 0; i < 40; ++i)
        tree.setValue(openvdb::Coord(200 + i, 30, 40 - i), 0.01f * float(i));
    return nanovdb::openToNanoVDB(*g);
}

const std::vector<WalkGrid> &walk_grids() {
    static std::vector<WalkGrid> grids = [] {
        std::vector<WalkGrid> out;
        for (const char *name : { "fog_sphere", "noisy_cloud", "random_cube", "lower_tiles",
                                  "upper_tiles", "root_tiles_negative", "far_coords",
                                  "single_voxel", "nonzero_background" })
            out.push_back(make_walk_grid(name, nvdb_test::make_nano_grid(name)));
        out.push_back(make_walk_grid("mixed_tiles", mixed_tiles()));
        for (const char *name : { "noisy_cloud", "lower_tiles", "upper_tiles", "nonzero_background" })
            for (const char *type : { "fp8", "fpn", "half", "vec3f" }) {
                nvdb_test::TypedGrid t = nvdb_test::make_typed_grid(name, type);
                out.push_back(make_walk_grid(name, nvdb_test::make_nano_grid(name), &t));
            }
        for (const char *name : { "fog_sphere", "noisy_cloud", "lower_tiles", "upper_tiles" })
            out.push_back(make_index_walk_grid(name, nvdb_test::make_nano_grid(name)));
        out.push_back(make_index_walk_grid("mixed_tiles", mixed_tiles()));
        return out;
    }();
    return grids;
}

struct Ray {
    float o[3], d[3], tmin, tmax, coarse_limit;
};

/// Rays from random points around the index box (cell space, relative to
/// the base) to random points of it, at several speeds (|d|: voxels per
/// unit of t); some axis-parallel, some starting late
std::vector<Ray> random_rays(const WalkGrid &g, uint64_t seed, bool coarse) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    std::vector<Ray> rays(RAY_COUNT);
    for (size_t i = 0; i < RAY_COUNT; ++i) {
        Ray &r = rays[i];
        double from[3], to[3], len = 0;
        for (int a = 0; a < 3; ++a) {
            const double lo = double(g.lo[a]) - double(g.base[a]),
                         ext = double(g.hi[a]) - double(g.lo[a]) + 1.0;
            // Far grids (far_coords) span millions of voxels: aim near the box corners too
            const double span = std::min(ext, 600.0), margin = 24.0;
            const double start = (i % 2 == 0) ? lo : lo + ext - span;
            from[a] = start - margin + u(rng) * (span + 2 * margin);
            to[a] = start + u(rng) * span;
        }
        if (i % 9 < 3) // axis-parallel on one axis
            to[i % 3] = from[i % 3];
        for (int a = 0; a < 3; ++a)
            len += (to[a] - from[a]) * (to[a] - from[a]);
        len = std::max(std::sqrt(len), 1e-3);
        const double speed = (i % 4 == 0) ? 0.37 : (i % 4 == 1) ? 1.0 : (i % 4 == 2) ? 3.0 : 11.0;
        for (int a = 0; a < 3; ++a) {
            r.o[a] = float(from[a]);
            r.d[a] = float((to[a] - from[a]) / len * speed);
        }
        r.tmin = (i % 5 == 0) ? float(u(rng) * 10.0 / speed) : 0.f;
        r.tmax = float((len + 40.0) / speed);
        r.coarse_limit = coarse ? float((i % 3) * 40.0 * u(rng)) : 0.f;
    }
    return rays;
}

struct Segment {
    float t0, t1, majorant;
    float control = 0.f, minorant = 0.f; ///< with controls
};

/// Calls fn(std::integral_constant<uint32_t, T>) for a grid type
template <typename Fn> decltype(auto) with_type(uint32_t grid_type, Fn &&fn) {
    return ndr::layout::visit_value_type(grid_type, std::forward<Fn>(fn));
}

/// The scalar walk of one ray
template <typename Buffer, typename Root>
std::vector<Segment> walk_scalar(const Buffer &buf, const Root &root,
                                 const ndr::MajorantGrid<uint32_t> &mg, const Ray &r,
                                 uint32_t grid_type, bool controls = false) {
    using V = dr::Array<float, 3>;
    const V o(r.o[0], r.o[1], r.o[2]), d(r.d[0], r.d[1], r.d[2]);
    return with_type(grid_type, [&](auto type) {
        constexpr uint32_t T = decltype(type)::value;
        ndr::MajorantWalk<float> w =
            ndr::walk_begin<T>(buf, root, mg, o, d, r.tmin, r.tmax, r.coarse_limit, true, controls);
        std::vector<Segment> out;
        for (int s = 0; s < MAX_STEPS && ndr::walk_valid(w); ++s) {
            out.push_back({ w.hdda.tmin, w.segment_end(), w.majorant, w.control, w.minorant });
            ndr::walk_advance<T>(buf, root, mg, w, o, d, r.coarse_limit, true, controls);
        }
        return out;
    });
}

ndr::MajorantGrid<uint32_t> scalar_majorants(const WalkGrid &g,
                                             const loader::NodeMajorants *other = nullptr) {
    const loader::NodeMajorants &m = other ? *other : g.majorants;
    ndr::MajorantGrid<uint32_t> mg = ndr::MajorantGrid<uint32_t>::make(
        m.layout, m.values, 1.f, std::numeric_limits<float>::infinity(), g.base);
    mg.set_root_tiles(m.tile_origins, g.base, g.lo, g.hi); // (as the plugin)
    return mg;
}

/// PNanoVDB's value at an absolute coordinate (its per-type readers)
struct Reference {
    pnanovdb_buf_t buf;
    pnanovdb_root_handle_t root;
    uint32_t type;
    const WalkGrid *grid;
    explicit Reference(const WalkGrid &g) : type(g.grid_type), grid(&g) {
        buf.data = const_cast<uint32_t *>(g.words.data());
        pnanovdb_grid_handle_t grid = { pnanovdb_address_null() };
        root = pnanovdb_tree_get_root(buf, pnanovdb_grid_get_tree(buf, grid));
    }
    float value(int64_t i, int64_t j, int64_t k) const {
        if (type == ndr::layout::GRID_TYPE_ONINDEX) { // (beyond PNanoVDB 32.4): the translation's index
            constexpr uint32_t T = ndr::layout::GRID_TYPE_ONINDEX;
            const ndr::Coord<uint32_t> c{ int32_t(uint32_t(i)), int32_t(uint32_t(j)), int32_t(uint32_t(k)) };
            const uint32_t index = ndr::Reader<uint32_t>::from_plan(grid->plan.faithful()).apply(
                grid->words.data(), [&](const auto &b, const auto &r) {
                    ndr::AddressAndLevel<uint32_t> al = ndr::value_address_and_level<T>(b, r, c, true);
                    return ndr::root_read_index<T>(b, al.address, al.level, c, true);
                });
            return index == 0 ? grid->index_background : grid->index_values[index - 1];
        }
        pnanovdb_coord_t ijk = { int32_t(uint32_t(i)), int32_t(uint32_t(j)), int32_t(uint32_t(k)) };
        pnanovdb_uint32_t level;
        const pnanovdb_address_t a =
            pnanovdb_root_get_value_address_and_level(type, buf, root, &ijk, &level);
        switch (type) {
            case PNANOVDB_GRID_TYPE_FP8: return pnanovdb_root_fp8_read_float(buf, a, &ijk, level);
            case PNANOVDB_GRID_TYPE_FPN: return pnanovdb_root_fpn_read_float(buf, a, &ijk, level);
            case PNANOVDB_GRID_TYPE_HALF:
                return nvdb_test::f16c_to_float(uint16_t(pnanovdb_read_half(buf, a)));
            case PNANOVDB_GRID_TYPE_VEC3F: // the largest channel: what a majorant bounds
                return std::max(pnanovdb_read_float(buf, a),
                                std::max(pnanovdb_read_float(buf, pnanovdb_address_offset(a, 4)),
                                         pnanovdb_read_float(buf, pnanovdb_address_offset(a, 8))));
            default: return pnanovdb_read_float(buf, a);
        }
    }
};

/// The bound of the finest cell holding absolute voxel ijk (tests/hand_walk.h)
float expected_bound(const WalkGrid &g, const nanovdb::Coord &ijk) {
    return nvdb_test::finest_bound(*g.handle.grid<float>(), g.majorants, ijk);
}

} // namespace

TEST_CASE("majorant walk: segments tile the ray and bound every lookup in them") {
    for (const WalkGrid &g : walk_grids()) {
        SUBCASE(g.name.c_str()) {
            ndr::Reader<uint32_t> reader = ndr::Reader<uint32_t>::from_plan(g.plan);
            const ndr::MajorantGrid<uint32_t> mg = scalar_majorants(g);
            const Reference ref(g);
            std::mt19937_64 rng(17);
            std::uniform_real_distribution<double> u(0.0, 1.0);
            for (bool coarse : { false, true }) {
                const std::vector<Ray> rays = random_rays(g, coarse ? 2 : 1, coarse);
                size_t segments = 0, points = 0, gaps = 0, exceed = 0, wrong_bound = 0,
                       truncated = 0, bad_control = 0, below = 0;
                const size_t per_ray = POINTS_PER_GRID / RAY_COUNT / 2;
                // The faithful readers (64-bit child offsets, the root's linear
                // search) must walk exactly as the plan's
                ndr::Reader<uint32_t> faithful = ndr::Reader<uint32_t>::from_plan(g.plan.faithful());
                size_t reader_mismatches = 0;
                for (const Ray &r : rays) {
                    std::vector<Segment> segs = reader.apply(
                        g.words.data(), [&](const auto &buf, const auto &root) {
                            return walk_scalar(buf, root, mg, r, g.grid_type);
                        });
                    std::vector<Segment> segs_faithful = faithful.apply(
                        g.words.data(), [&](const auto &buf, const auto &root) {
                            return walk_scalar(buf, root, mg, r, g.grid_type);
                        });
                    if (segs.size() != segs_faithful.size() ||
                        (!segs.empty() && std::memcmp(segs.data(), segs_faithful.data(),
                                                      segs.size() * sizeof(Segment)) != 0))
                        ++reader_mismatches;
                    // With controls: the same segments, each with its control
                    // and lower bound (checked at the points below)
                    std::vector<Segment> segs_c = reader.apply(
                        g.words.data(), [&](const auto &buf, const auto &root) {
                            return walk_scalar(buf, root, mg, r, g.grid_type, true);
                        });
                    bool same = segs_c.size() == segs.size();
                    for (size_t s = 0; same && s < segs.size(); ++s) {
                        same = segs_c[s].t0 == segs[s].t0 && segs_c[s].t1 == segs[s].t1 &&
                               segs_c[s].majorant == segs[s].majorant;
                        if (!(segs_c[s].minorant >= 0.f && segs_c[s].minorant <= segs_c[s].control &&
                              segs_c[s].control <= segs_c[s].majorant) && ++bad_control <= 5) {
                            INFO("segment " << s << ": minorant " << segs_c[s].minorant << ", control "
                                            << segs_c[s].control << ", majorant " << segs_c[s].majorant);
                            CHECK(false);
                        }
                    }
                    if (!same)
                        ++reader_mismatches;
                    segs = std::move(segs_c);
                    if (r.tmin < r.tmax && segs.empty()) {
                        ++gaps;
                        continue;
                    }
                    if (segs.size() == size_t(MAX_STEPS)) {
                        ++truncated;
                        continue;
                    }
                    segments += segs.size();
                    for (size_t s = 0; s < segs.size(); ++s) {
                        const Segment &sg = segs[s];
                        const float prev = s == 0 ? r.tmin : segs[s - 1].t1;
                        // Contiguous; forward stepping may push a boundary by ~1e-6 relative
                        if (!(std::fabs(sg.t0 - prev) <= 2e-6f * std::max(1.f, std::fabs(prev))) ||
                            !(sg.t1 >= sg.t0))
                            ++gaps;
                        if (!coarse && g.grid_type == 1) {
                            const double tm = 0.5 * (double(sg.t0) + double(sg.t1));
                            nanovdb::Coord c;
                            for (int a = 0; a < 3; ++a)
                                c[a] = int32_t(uint32_t(int64_t(std::floor(r.o[a] + r.d[a] * tm)) +
                                                        int64_t(g.base[a])));
                            // Only where the midpoint is clear of a cell boundary
                            bool clear = true;
                            for (int a = 0; a < 3; ++a) {
                                const double q = r.o[a] + r.d[a] * tm, f = q - std::floor(q);
                                clear &= f > 1e-3 && f < 1 - 1e-3;
                            }
                            if (clear && sg.t1 - sg.t0 > 1e-3f &&
                                expected_bound(g, c) != sg.majorant && ++wrong_bound <= 5) {
                                INFO("segment [" << sg.t0 << ", " << sg.t1 << "] at " << c[0]
                                                 << " " << c[1] << " " << c[2] << ": bound "
                                                 << sg.majorant << ", expected "
                                                 << expected_bound(g, c));
                                CHECK(false);
                            }
                        }
                    }
                    if (!segs.empty() && std::fabs(segs.back().t1 - r.tmax) > 0.f)
                        ++gaps;
                    // Lookups at random points of random segments
                    for (size_t k = 0; k < per_ray && !segs.empty(); ++k) {
                        const Segment &sg = segs[rng() % segs.size()];
                        const double t = sg.t0 + u(rng) * (double(sg.t1) - double(sg.t0));
                        double q[3];
                        for (int a = 0; a < 3; ++a)
                            q[a] = double(r.o[a]) + double(r.d[a]) * t + double(g.base[a]);
                        float v = ref.value(int64_t(std::floor(q[0])), int64_t(std::floor(q[1])),
                                            int64_t(std::floor(q[2])));
                        float lo = v;
                        const int64_t b[3] = { int64_t(std::floor(q[0] - 0.5)),
                                               int64_t(std::floor(q[1] - 0.5)),
                                               int64_t(std::floor(q[2] - 0.5)) };
                        for (int corner = 0; corner < 8; ++corner) {
                            const float c = ref.value(b[0] + (corner & 1), b[1] + (corner >> 1 & 1),
                                                      b[2] + (corner >> 2 & 1));
                            if (c > v || std::isnan(v))
                                v = c;
                            if (c < lo || std::isnan(lo))
                                lo = c;
                        }
                        // The lower bound: at most every value read there (to the
                        // rounding of one product); negative values (level sets)
                        // are below every lower bound, which is >= 0 (a medium's
                        // density is)
                        if (lo >= 0.f && lo < sg.minorant * (1.f - 1e-6f) && ++below <= 5) {
                            INFO("point t = " << t << " in [" << sg.t0 << ", " << sg.t1
                                              << "]: value " << lo << " < lower bound " << sg.minorant
                                              << " (control " << sg.control << ", bound "
                                              << sg.majorant << ")");
                            CHECK(false);
                        }
                        ++points;
                        if (v > sg.majorant && ++exceed <= 5) {
                            INFO("point t = " << t << " in [" << sg.t0 << ", " << sg.t1
                                              << "]: value " << v << " > bound " << sg.majorant);
                            CHECK(false);
                        }
                    }
                }
                const std::string label = g.name + (coarse ? " (coarse)" : "");
                MESSAGE(label, ": ", rays.size(), " rays, ", segments,
                        " segments, ", points, " points; ", gaps, " gaps, ", exceed,
                        " bounds exceeded, ", wrong_bound, " wrong bounds, ", truncated,
                        " truncated, ", below, " below the lower bound, ", bad_control,
                        " controls out of order");
                CHECK(reader_mismatches == 0);
                CHECK(gaps == 0);
                CHECK(exceed == 0);
                CHECK(below == 0);
                CHECK(bad_control == 0);
                CHECK(wrong_bound == 0);
                CHECK(truncated == 0);
                CHECK(points >= POINTS_PER_GRID / 2 - RAY_COUNT);
            }
        }
    }
}

TEST_CASE("majorant walk: LLVM equals scalar step for step") {
    jit_init(1u << (uint32_t) JitBackend::LLVM);
    using Float = dr::LLVMArray<float>;
    using UInt32 = dr::uint32_array_t<Float>;
    using Vec = dr::Array<Float, 3>;
    for (const WalkGrid &g : walk_grids()) {
        SUBCASE(g.name.c_str()) {
            const std::vector<Ray> rays = random_rays(g, 3, true);
            const size_t n = rays.size();
            std::vector<float> f[9];
            for (auto &v : f)
                v.resize(n);
            for (size_t i = 0; i < n; ++i) {
                for (int a = 0; a < 3; ++a) {
                    f[a][i] = rays[i].o[a];
                    f[3 + a][i] = rays[i].d[a];
                }
                f[6][i] = rays[i].tmin;
                f[7][i] = rays[i].tmax;
                f[8][i] = rays[i].coarse_limit;
            }
            auto load = [&](int k) { return dr::load<Float>(f[k].data(), n); };
            const Vec o(load(0), load(1), load(2)), d(load(3), load(4), load(5));
            const Float tmin = load(6), tmax = load(7), limit = load(8);

            UInt32 grid_words = dr::load<UInt32>(g.words.data(), g.words.size());
            ndr::Reader<UInt32> reader = ndr::Reader<UInt32>::from_plan(g.plan);
            auto mg = ndr::MajorantGrid<UInt32>::make(
                g.majorants.layout, g.majorants.values, 1.f,
                std::numeric_limits<float>::infinity(), g.base);
            mg.set_root_tiles(g.majorants.tile_origins, g.base, g.lo, g.hi);
            const ndr::MajorantGrid<uint32_t> mgs = scalar_majorants(g);
            ndr::Reader<uint32_t> sreader = ndr::Reader<uint32_t>::from_plan(g.plan);

            std::vector<std::vector<Segment>> want(n);
            for (size_t i = 0; i < n; ++i)
                want[i] = sreader.apply(g.words.data(), [&](const auto &buf, const auto &root) {
                    return walk_scalar(buf, root, mgs, rays[i], g.grid_type);
                });

            ndr::MajorantWalk<Float> w = with_type(g.grid_type, [&](auto type) {
                return reader.apply(grid_words, [&](const auto &b, const auto &r) {
                    return ndr::walk_begin<decltype(type)::value>(b, r, mg, o, d, tmin, tmax,
                                                                  limit, true);
                });
            });
            size_t mismatches = 0, compared = 0;
            for (int s = 0; s < MAX_STEPS; ++s) {
                dr::eval(w);
                std::vector<float> t0(n), t1(n), m(n);
                std::vector<uint32_t> valid(n);
                dr::store(t0.data(), w.hdda.tmin);
                dr::store(t1.data(), w.segment_end());
                dr::store(m.data(), w.majorant);
                dr::store(valid.data(), dr::select(ndr::walk_valid(w), UInt32(1), UInt32(0)));
                bool any = false;
                for (size_t i = 0; i < n; ++i) {
                    const bool has = size_t(s) < want[i].size();
                    if (bool(valid[i]) != has) {
                        ++mismatches;
                        continue;
                    }
                    if (!has)
                        continue;
                    any = true;
                    ++compared;
                    const Segment &e = want[i][size_t(s)];
                    if (std::memcmp(&e.t0, &t0[i], 4) || std::memcmp(&e.t1, &t1[i], 4) ||
                        std::memcmp(&e.majorant, &m[i], 4)) {
                        if (++mismatches <= 5) {
                            INFO("ray " << i << " step " << s << ": scalar [" << e.t0 << ", "
                                        << e.t1 << "] " << e.majorant << ", LLVM [" << t0[i]
                                        << ", " << t1[i] << "] " << m[i]);
                            CHECK(false);
                        }
                    }
                }
                if (!any)
                    break;
                with_type(g.grid_type, [&](auto type) {
                    return reader.apply(grid_words, [&](const auto &b, const auto &r) {
                        ndr::walk_advance<decltype(type)::value>(b, r, mg, w, o, d, limit,
                                                                 ndr::walk_valid(w));
                        return 0;
                    });
                });
            }
            MESSAGE(g.name, ": ", compared, " segments compared, ", mismatches, " mismatches");
            CHECK(mismatches == 0);
        }
    }
}

TEST_CASE("majorant table: many threads build what one thread builds, bit for bit") {
    // (node_majorants bounds the lower nodes in parallel, each thread with
    // its own scratch and its own nodes' slots: a shared scratch or a race
    // on a slot shows up here as a differing table)
    for (const WalkGrid &g : walk_grids()) {
        CAPTURE(g.name);
        const loader::ValidatedGrid v =
            g.index_values.empty()
                ? loader::validate_grid(g.name, g.words.data(), g.words.size() * 4)
                : loader::validate_grid(g.name, g.words.data(), g.words.size() * 4,
                                        loader::IndexValues{
                                            const_cast<float *>(g.index_values.data()),
                                            g.index_values.size(),
                                            { g.index_background, g.index_background,
                                              g.index_background } });
        for (int ring : { 1, 2 }) {
            const loader::NodeMajorants one = loader::node_majorants(v, ring, 1),
                                        many = loader::node_majorants(v, ring, 7);
            CHECK(one.values.size() == many.values.size());
            CHECK(std::memcmp(one.values.data(), many.values.data(),
                              4 * std::min(one.values.size(), many.values.size())) == 0);
            CHECK(one.tile_origins == many.tile_origins);
            // (and the loader's default, as the plugin calls it: ring 1)
            if (ring == 1)
                CHECK(std::memcmp(one.values.data(), g.majorants.values.data(),
                                  4 * std::min(one.values.size(),
                                               g.majorants.values.size())) == 0);
        }
    }
}

/// The backend's rebuild (nanovdb_drjit/majorant_rebuild.h, LLVM) of an
/// index grid's table from `values`, as MajorantGrid::make writes it
/// (and its mean bound over `box`, clamped to `clamp`)
std::vector<uint32_t> rebuilt_table(const ndr::MajorantRebuild<dr::LLVMArray<float>> &rebuild,
                                    const std::vector<uint32_t> &words,
                                    const std::vector<float> &values, float background,
                                    float factor, const loader::IndexBox &box, float clamp,
                                    double &mean) {
    using Float = dr::LLVMArray<float>;
    using UInt32 = dr::uint32_array_t<Float>;
    const float bg[3] = { background, background, background };
    typename ndr::MajorantRebuild<Float>::Box b;
    for (int a = 0; a < 3; ++a) {
        b.lo[a] = box.lo[a];
        b.hi[a] = box.hi[a];
    }
    b.clamp = clamp;
    const Float v = dr::load<Float>(values.data(), values.size());
    const UInt32 table = rebuild.table(dr::load<UInt32>(words.data(), words.size()), v, 1, bg, factor);
    const dr::LLVMArray<double> m = rebuild.mean(table, v, 1, bg, factor, b);
    std::vector<uint32_t> out(dr::width(table));
    dr::store(out.data(), table);
    mean = m.entry(0);
    return out;
}

/// The words MajorantGrid::make makes of the loader's table
std::vector<uint32_t> host_table(const loader::NodeMajorants &m, float factor) {
    const int32_t base[3] = { 0, 0, 0 };
    const ndr::MajorantGrid<uint32_t> g =
        ndr::MajorantGrid<uint32_t>::make(m.layout, m.values, factor, 1.f, base);
    return g.table;
}

TEST_CASE("majorant table: the backend's rebuild equals the host's, bit for bit") {
    // Index grids of every test grid, their values then changed as an
    // update changes them (raised 100x, set to 0, scaled), rebuilt on LLVM
    // from the values and the plan alone; against node_majorants of the
    // same values, for rings 1 and 2. Each update twice, the second time
    // with its values halved: one rebuild per grid and ring, whose second
    // call replays the first's kernels (kernel_replay.h)
    jit_init(1u << (uint32_t) JitBackend::LLVM);
    using Rebuild = ndr::MajorantRebuild<dr::LLVMArray<float>>;
    std::map<std::pair<std::string, int>, Rebuild> rebuilds;
    uint32_t replays = 0;
    std::vector<std::pair<std::string, Handle>> handles;
    for (const char *name : { "fog_sphere", "noisy_cloud", "random_cube", "lower_tiles",
                              "upper_tiles", "root_tiles_negative", "far_coords", "single_voxel",
                              "nonzero_background" })
        handles.emplace_back(name, nvdb_test::make_nano_grid(name));
    handles.emplace_back("mixed_tiles", mixed_tiles());
    size_t compared = 0;
    for (auto &[name, handle] : handles) {
        CAPTURE(name);
        std::vector<uint32_t> words((handle.size() + 3) / 4);
        std::memcpy(words.data(), handle.data(), handle.size());
        const loader::MadeIndexGrid made =
            loader::make_index_grid(loader::validate_grid(name, words.data(), handle.size()));
        std::vector<uint32_t> index_words((made.bytes.size() + 3) / 4);
        std::memcpy(index_words.data(), made.bytes.data(), made.bytes.size());
        for (int update = 0; update < 3; ++update) {
            CAPTURE(update);
            // 0: raised, zeroed, scaled at random; 1: all one value (nodes of
            // one bound); 2: all 0
            std::vector<float> values = made.values.values;
            std::mt19937_64 rng(5);
            std::uniform_real_distribution<float> u(0.f, 1.f);
            for (float &x : values) {
                const float r = u(rng);
                x = update == 1 ? 0.5f : update == 2 ? 0.f
                    : r < 0.1f ? 100.f * x : r < 0.4f ? 0.f : x * 3.f * u(rng);
            }
            const float background = update == 0 ? made.values.background[0] : values.empty() ? 0.f : values[0];
            for (int again = 0; again < 2; ++again) {
                CAPTURE(again);
                if (again)
                    for (float &x : values)
                        x *= 0.5f;
                const loader::ValidatedGrid v = loader::validate_grid(
                    name, index_words.data(), made.bytes.size(),
                    loader::IndexValues{ values.data(), values.size(),
                                         { background, background, background } });
                for (int ring : { 1, 2 }) {
                    CAPTURE(ring);
                    std::string why;
                    const std::optional<ndr::MajorantRebuildPlan> plan =
                        loader::majorant_rebuild_plan(v, ring, &why);
                    CAPTURE(why);
                    REQUIRE(plan.has_value());
                    const float factor = 1.f + 0x1p-20f;
                    const loader::NodeMajorants host = loader::node_majorants(v, ring);
                    const loader::IndexBox box = loader::lookup_box(v.summary(), 1);
                    // (the second time below the values: the clamp binds)
                    const float clamp = again ? 0.25f * v.values().max : v.values().max;
                    double mean = 0.0;
                    // (ring 2: 7 leaves and 1 lower node a pass, so that the
                    // passes must join; ring 1: the defaults)
                    const bool small_chunks = ring == 2;
                    auto at = rebuilds.try_emplace(
                        { name, ring }, *plan, small_chunks ? 7u : 1u << 16, small_chunks ? 1u : 256u).first;
                    const uint32_t replays_before = at->second.replay().replays(),
                                   mean_replays_before = at->second.mean_replay().replays();
                    const std::vector<uint32_t> want = host_table(host, factor),
                                                got = rebuilt_table(at->second, index_words, values,
                                                                    background, factor, box, clamp, mean);
                    // (the same constants as the call before: a replay)
                    if (again) {
                        CHECK(at->second.replay().replays() == replays_before + 1);
                        CHECK(at->second.mean_replay().replays() == mean_replays_before + 1);
                    }
                    replays += at->second.replay().replays() - replays_before;
                    // (the mean bound, to rounding: another order of sums, bounds x
                    // factor / factor)
                    const double mean_want = loader::mean_bound(v, host, box, clamp);
                    CHECK(std::abs(mean - mean_want) <= 1e-6 * mean_want + 1e-30);
                    REQUIRE(got.size() == want.size());
                    size_t differ = 0, first = want.size();
                    for (size_t i = 0; i < want.size(); ++i)
                        if (got[i] != want[i]) {
                            if (differ++ == 0)
                                first = i;
                        }
                    CAPTURE(first);
                    CHECK(differ == 0);
                    compared += want.size();
                }
            }
        }
    }
    MESSAGE(compared << " slots compared, " << replays << " of the rebuilds replayed");
    CHECK(replays > 0);
}

TEST_CASE("majorant walk: a ring of 2 bounds the tricubic reach, a ring of 1 does not") {
    size_t exceeded_by_ring1 = 0;
    for (const WalkGrid &g : walk_grids()) {
        if (g.grid_type != 1)
            continue; // (float grids: the ring is built the same for every type)
        loader::ValidatedGrid v = loader::validate_grid(g.name, g.words.data(), g.handle.size());
        const loader::NodeMajorants ring2 = loader::node_majorants(v, 2);
        ndr::Reader<uint32_t> reader = ndr::Reader<uint32_t>::from_plan(g.plan);
        const Reference ref(g);
        std::mt19937_64 rng(23);
        std::uniform_real_distribution<double> u(0.0, 1.0);
        size_t points = 0, exceed[2] = { 0, 0 };
        for (int ring : { 1, 2 }) {
            const ndr::MajorantGrid<uint32_t> mg = scalar_majorants(g, ring == 2 ? &ring2 : nullptr);
            for (const Ray &r : random_rays(g, 3, false)) {
                std::vector<Segment> segs = reader.apply(
                    g.words.data(), [&](const auto &buf, const auto &root) {
                        return walk_scalar(buf, root, mg, r, g.grid_type);
                    });
                for (size_t k = 0; k < 40 && !segs.empty(); ++k) {
                    const Segment &sg = segs[rng() % segs.size()];
                    const double t = sg.t0 + u(rng) * (double(sg.t1) - double(sg.t0));
                    // The 4^3 taps of a B-spline lookup at q (cell space:
                    // values at voxel centres), b = floor(q - 1/2)
                    int64_t b[3];
                    for (int a = 0; a < 3; ++a)
                        b[a] = int64_t(std::floor(double(r.o[a]) + double(r.d[a]) * t +
                                                  double(g.base[a]) - 0.5));
                    float v = -INFINITY;
                    for (int i = -1; i <= 2; ++i)
                        for (int j = -1; j <= 2; ++j)
                            for (int l = -1; l <= 2; ++l)
                                v = std::max(v, ref.value(b[0] + i, b[1] + j, b[2] + l));
                    points += ring == 2;
                    exceed[ring - 1] += v > sg.majorant;
                }
            }
        }
        MESSAGE(g.name, ": ", points, " points, tricubic taps above the bound: ring 1 ",
                exceed[0], ", ring 2 ", exceed[1]);
        CHECK(exceed[1] == 0);
        exceeded_by_ring1 += exceed[0];
    }
    CHECK(exceeded_by_ring1 > 0);
}

TEST_CASE("majorant walk: empty root space in one step, stopping at the next root tile") {
    // far_coords: root tiles up to 2e9 voxels apart. Rays from the
    // background, 1e4 to 1e6 voxels away, to the voxels of the 3^3 block at
    // (-1000000001)^3, the one near the walk's base (small cell-space
    // coordinates: exact floats): the walk must jump to its root tile, not
    // past it (every block voxel's value is within its segment's bound),
    // and cross the empty root space in one step, not one per 4096^3 cell
    const WalkGrid *g = nullptr;
    for (const WalkGrid &w : walk_grids())
        if (w.name == "far_coords")
            g = &w;
    REQUIRE(g != nullptr);
    ndr::Reader<uint32_t> reader = ndr::Reader<uint32_t>::from_plan(g->plan);
    const ndr::MajorantGrid<uint32_t> mg = scalar_majorants(*g);
    REQUIRE(mg.far_jumps);
    ndr::MajorantGrid<uint32_t> cell_by_cell = scalar_majorants(*g);
    cell_by_cell.far_jumps = false;
    size_t steps = 0, steps_cell_by_cell = 0;
    const Reference ref(*g);
    std::mt19937_64 rng(29);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    size_t rays = 0, exceed = 0, gaps = 0, most_steps = 0;
    for (double distance : { 1e4, 1e5, 1e6 })
        for (int n = 0; n < 40; ++n) {
            // The target: a block voxel's centre (cell space, relative to base)
            const int64_t c[3] = { -1000000001 + n % 3 - 1, -1000000001 + n / 3 % 3 - 1,
                                   -1000000001 + n / 9 % 3 - 1 };
            double target[3], dir[3], len = 0;
            for (int a = 0; a < 3; ++a) {
                target[a] = double(c[a] - int64_t(g->base[a])) + 0.5;
                dir[a] = u(rng);
                len += dir[a] * dir[a];
            }
            len = std::sqrt(len);
            Ray r;
            for (int a = 0; a < 3; ++a) {
                r.d[a] = float(dir[a] / len);
                r.o[a] = float(target[a] - distance * dir[a] / len);
            }
            // (t of the target, with the rounded ray)
            double t_target = 0;
            for (int a = 0; a < 3; ++a)
                t_target += (target[a] - double(r.o[a])) * double(r.d[a]);
            r.tmin = 0.f;
            r.tmax = float(2 * distance);
            r.coarse_limit = 0.f;
            const std::vector<Segment> segs = reader.apply(
                g->words.data(), [&](const auto &buf, const auto &root) {
                    return walk_scalar(buf, root, mg, r, g->grid_type);
                });
            ++rays;
            most_steps = std::max(most_steps, segs.size());
            steps += segs.size();
            steps_cell_by_cell += reader.apply(g->words.data(), [&](const auto &buf,
                                                                      const auto &root) {
                return walk_scalar(buf, root, cell_by_cell, r, g->grid_type);
            }).size();
            if (segs.empty() || segs.back().t1 != r.tmax)
                ++gaps;
            for (size_t s = 1; s < segs.size(); ++s)
                gaps += !(std::fabs(segs[s].t0 - segs[s - 1].t1) <=
                          2e-6f * std::max(1.f, std::fabs(segs[s - 1].t1)));
            // The segment holding the target, and the value there
            for (const Segment &sg : segs)
                if (sg.t0 <= t_target && t_target < sg.t1) {
                    const float v = ref.value(c[0], c[1], c[2]);
                    if (v > sg.majorant && ++exceed <= 3) {
                        INFO("distance " << distance << ": voxel value " << v
                                         << " in a segment bounded by " << sg.majorant
                                         << " [" << sg.t0 << ", " << sg.t1 << "]");
                        CHECK(false);
                    }
                }
        }
    MESSAGE("far_coords: ", rays, " rays from 1e4-1e6 voxels away: ", steps, " steps (at most ",
            most_steps, " per ray), ", steps_cell_by_cell, " cell by cell");
    CHECK(exceed == 0);
    CHECK(gaps == 0);
    // (the steps left are those inside the target's root tile: every node)
    CHECK(steps * 2 < steps_cell_by_cell);
}
