/*
    The hierarchical DDA (include/nanovdb_drjit/hdda.h) against PNanoVDB's
    own C code (pnanovdb_hdda_*), step for step: on random rays through index
    space (origins anywhere, directions with zero and negative-zero
    components, any tmin/tmax), with the cell size changing at random between
    1, 8, 128 and 4096 before every step (pnanovdb_hdda_update), every field
    of the walk's state must be bit-identical after every step, on scalar and
    LLVM. Also pnanovdb_hdda_ray_clip on random boxes.

    This file is compiled with -ffp-contract=off (tests/CMakeLists.txt), so
    the C reference rounds a * b + c twice, as PNanoVDB's arithmetic says.
*/

#define PNANOVDB_C
#define PNANOVDB_ADDRESS_64
#define PNANOVDB_HDDA
#include <nanovdb/PNanoVDB.h>

#include <nanovdb_drjit/hdda.h>
#include <drjit/jit.h>
#include <drjit-core/jit.h>

#include <doctest/doctest.h>

#include <cstring>
#include <random>
#include <vector>

namespace ndr = nanovdb_drjit;
namespace dr = drjit;

namespace {

constexpr size_t RAY_COUNT = 20000;
constexpr int STEP_COUNT = 48;

struct Ray {
    float origin[3], direction[3], tmin, tmax;
    int dims[STEP_COUNT + 1]; // dims[0]: init; dims[s]: the update before step s
};

std::vector<Ray> random_rays(uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<float> u(-1.f, 1.f);
    const int cell[4] = { 1, 8, 128, 4096 };
    std::vector<Ray> rays(RAY_COUNT);
    for (size_t i = 0; i < RAY_COUNT; ++i) {
        Ray &r = rays[i];
        const float scale = (i % 3 == 0) ? 5000.f : 200.f;
        for (int a = 0; a < 3; ++a) {
            r.origin[a] = u(rng) * scale;
            r.direction[a] = u(rng);
            // Axis-parallel rays: zero and negative-zero components
            if (i % 7 == size_t(a)) r.direction[a] = 0.f;
            if (i % 11 == size_t(a)) r.direction[a] = -0.f;
            // Origins on cell boundaries
            if (i % 5 == 0) r.origin[a] = float(int(r.origin[a]) & ~7);
        }
        r.tmin = (i % 4 == 0) ? 0.f : std::fabs(u(rng)) * 50.f;
        r.tmax = r.tmin + std::fabs(u(rng)) * 3000.f;
        for (int s = 0; s <= STEP_COUNT; ++s)
            r.dims[s] = (i % 2 == 0) ? cell[(s / 6 + i) % 4] : cell[rng() % 4];
    }
    return rays;
}

/// The walk's state after each step, as raw bits
struct Trace {
    std::vector<uint32_t> words; // per ray, per step: 16 words
    static constexpr int WORDS = 16;
    void resize(size_t rays) { words.assign(rays * (STEP_COUNT + 1) * WORDS, 0); }
    uint32_t *at(size_t ray, int step) { return &words[(ray * (STEP_COUNT + 1) + step) * WORDS]; }
};

template <typename T> uint32_t bits(T v) {
    uint32_t b;
    std::memcpy(&b, &v, 4);
    return b;
}

void record(uint32_t *w, int dim, float tmin, float tmax, const int32_t *voxel,
            const int32_t *step, const float *delta, const float *next, bool ret) {
    w[0] = bits(dim); w[1] = bits(tmin); w[2] = bits(tmax);
    for (int a = 0; a < 3; ++a) {
        w[3 + a] = bits(voxel[a]); w[6 + a] = bits(step[a]);
        w[9 + a] = bits(delta[a]); w[12 + a] = bits(next[a]);
    }
    w[15] = ret;
}

Trace walk_pnanovdb(const std::vector<Ray> &rays) {
    Trace t;
    t.resize(rays.size());
    for (size_t i = 0; i < rays.size(); ++i) {
        const Ray &r = rays[i];
        pnanovdb_vec3_t o = { r.origin[0], r.origin[1], r.origin[2] },
                        d = { r.direction[0], r.direction[1], r.direction[2] };
        pnanovdb_hdda_t h;
        pnanovdb_hdda_init(&h, &o, r.tmin, &d, r.tmax, r.dims[0]);
        auto rec = [&](int s, bool ret) {
            int32_t v[3] = { h.voxel.x, h.voxel.y, h.voxel.z }, st[3] = { h.step.x, h.step.y, h.step.z };
            float de[3] = { h.delta.x, h.delta.y, h.delta.z }, nx[3] = { h.next.x, h.next.y, h.next.z };
            record(t.at(i, s), h.dim, h.tmin, h.tmax, v, st, de, nx, ret);
        };
        rec(0, true);
        for (int s = 1; s <= STEP_COUNT; ++s) {
            pnanovdb_hdda_update(&h, &o, &d, r.dims[s]);
            rec(s, pnanovdb_hdda_step(&h));
        }
    }
    return t;
}

template <typename Float> Trace walk_translation(const std::vector<Ray> &rays) {
    using Int32 = dr::int32_array_t<Float>;
    using Vector3 = dr::Array<Float, 3>;
    Trace t;
    t.resize(rays.size());
    if constexpr (!dr::is_jit_v<Float>) {
        for (size_t i = 0; i < rays.size(); ++i) {
            const Ray &r = rays[i];
            Vector3 o(r.origin[0], r.origin[1], r.origin[2]),
                    d(r.direction[0], r.direction[1], r.direction[2]);
            ndr::Hdda<float> h = ndr::hdda_init(o, r.tmin, d, r.tmax, r.dims[0]);
            auto rec = [&](int s, bool ret) {
                int32_t v[3] = { h.voxel[0], h.voxel[1], h.voxel[2] }, st[3] = { h.step[0], h.step[1], h.step[2] };
                float de[3] = { h.delta[0], h.delta[1], h.delta[2] }, nx[3] = { h.next[0], h.next[1], h.next[2] };
                record(t.at(i, s), h.dim, h.tmin, h.tmax, v, st, de, nx, ret);
            };
            rec(0, true);
            for (int s = 1; s <= STEP_COUNT; ++s) {
                ndr::hdda_update(h, o, d, r.dims[s]);
                rec(s, ndr::hdda_step(h));
            }
        }
        return t;
    } else {
        const size_t n = rays.size();
        auto column = [&](auto get) {
            std::vector<float> v(n);
            for (size_t i = 0; i < n; ++i) v[i] = get(rays[i]);
            return dr::load<Float>(v.data(), n);
        };
        auto dims = [&](int s) {
            std::vector<int32_t> v(n);
            for (size_t i = 0; i < n; ++i) v[i] = rays[i].dims[s];
            return dr::load<Int32>(v.data(), n);
        };
        Vector3 o, d;
        for (int a = 0; a < 3; ++a) {
            o[a] = column([a](const Ray &r) { return r.origin[a]; });
            d[a] = column([a](const Ray &r) { return r.direction[a]; });
        }
        ndr::Hdda<Float> h = ndr::hdda_init(o, column([](const Ray &r) { return r.tmin; }), d,
                                            column([](const Ray &r) { return r.tmax; }), dims(0));
        auto rec = [&](int s, const dr::mask_t<Float> &ret) {
            dr::Array<Int32, 3> voxel = h.voxel, step = h.step;
            Vector3 delta = h.delta, next = h.next;
            Int32 dim = h.dim + dr::zeros<Int32>(n);
            Float tmin = h.tmin + dr::zeros<Float>(n), tmax = h.tmax + dr::zeros<Float>(n);
            dr::Array<Int32, 1> r1 = { dr::select(ret, Int32(1), Int32(0)) + dr::zeros<Int32>(n) };
            dr::eval(dim, tmin, tmax, voxel, step, delta, next, r1);
            std::vector<int32_t> iv(n);
            std::vector<float> fv(n);
            auto put_i = [&](const Int32 &x, int word) {
                dr::store(iv.data(), x);
                for (size_t i = 0; i < n; ++i) t.at(i, s)[word] = bits(iv[i]);
            };
            auto put_f = [&](const Float &x, int word) {
                dr::store(fv.data(), x);
                for (size_t i = 0; i < n; ++i) t.at(i, s)[word] = bits(fv[i]);
            };
            put_i(dim, 0); put_f(tmin, 1); put_f(tmax, 2);
            for (int a = 0; a < 3; ++a) {
                put_i(voxel[a], 3 + a); put_i(step[a], 6 + a);
                put_f(delta[a], 9 + a); put_f(next[a], 12 + a);
            }
            put_i(r1[0], 15);
        };
        rec(0, dr::full<dr::mask_t<Float>>(true, n));
        for (int s = 1; s <= STEP_COUNT; ++s) {
            ndr::hdda_update(h, o, d, dims(s));
            dr::mask_t<Float> ret = ndr::hdda_step(h);
            rec(s, ret);
        }
        return t;
    }
}

void compare(const char *backend, const std::vector<Ray> &rays, const Trace &ref, const Trace &got) {
    static const char *field[16] = { "dim", "tmin", "tmax", "voxel.x", "voxel.y", "voxel.z",
                                     "step.x", "step.y", "step.z", "delta.x", "delta.y", "delta.z",
                                     "next.x", "next.y", "next.z", "step result" };
    size_t mismatches = 0, steps_in_range = 0;
    for (size_t i = 0; i < rays.size(); ++i)
        for (int s = 0; s <= STEP_COUNT; ++s) {
            const uint32_t *a = const_cast<Trace &>(ref).at(i, s), *b = const_cast<Trace &>(got).at(i, s);
            steps_in_range += a[15];
            for (int w = 0; w < Trace::WORDS; ++w)
                if (a[w] != b[w] && ++mismatches <= 5) {
                    const Ray &r = rays[i];
                    INFO(backend << ": ray " << i << " (o " << r.origin[0] << " " << r.origin[1] << " "
                                 << r.origin[2] << ", d " << r.direction[0] << " " << r.direction[1]
                                 << " " << r.direction[2] << "), step " << s << ", " << field[w]);
                    CHECK(a[w] == b[w]);
                }
        }
    MESSAGE(std::string(backend), ": ", rays.size(), " rays x ", STEP_COUNT,
            " steps, every state field bit-identical to PNanoVDB: ", std::string(mismatches == 0 ? "yes" : "NO"),
            " (", steps_in_range, " steps before tmax)");
    CHECK(mismatches == 0);
}

} // namespace

TEST_CASE_TEMPLATE("hdda_init, hdda_update and hdda_step match PNanoVDB step for step", Float,
                   float, dr::LLVMArray<float>) {
    if constexpr (dr::is_jit_v<Float>) {
        jit_set_log_level_stderr(LogLevel::Warn);
        jit_init(1u << (uint32_t) JitBackend::LLVM);
    }
    static const std::vector<Ray> rays = random_rays(42);
    static const Trace ref = walk_pnanovdb(rays);
    compare(dr::is_jit_v<Float> ? "LLVM" : "scalar", rays, ref, walk_translation<Float>(rays));
}

TEST_CASE("hdda_ray_clip matches PNanoVDB") {
    std::mt19937_64 rng(3);
    std::uniform_real_distribution<float> u(-1.f, 1.f);
    size_t mismatches = 0, hits = 0;
    for (int i = 0; i < 200000; ++i) {
        float lo[3], hi[3], o[3], d[3];
        for (int a = 0; a < 3; ++a) {
            lo[a] = std::floor(u(rng) * 100.f);
            hi[a] = lo[a] + 1.f + std::floor(std::fabs(u(rng)) * 80.f);
            o[a] = u(rng) * 200.f;
        }
        for (int a = 0; a < 3; ++a) {
            // Half of the rays aim at the box (with jitter), the rest anywhere
            const float aim = (lo[a] + hi[a]) * 0.5f - o[a];
            d[a] = (i % 9 == a) ? 0.f : (i % 2 ? aim * (1.f + 0.3f * u(rng)) : u(rng));
        }
        float t0 = (i % 2) ? 0.f : std::fabs(u(rng)) * 10.f, t1 = 1e30f;
        pnanovdb_vec3_t plo = { lo[0], lo[1], lo[2] }, phi = { hi[0], hi[1], hi[2] },
                        po = { o[0], o[1], o[2] }, pd = { d[0], d[1], d[2] };
        float pt0 = t0, pt1 = t1;
        bool phit = pnanovdb_hdda_ray_clip(&plo, &phi, &po, &pt0, &pd, &pt1);
        dr::Array<float, 3> blo(lo[0], lo[1], lo[2]), bhi(hi[0], hi[1], hi[2]),
                            bo(o[0], o[1], o[2]), bd(d[0], d[1], d[2]);
        float gt0 = t0, gt1 = t1;
        bool ghit = ndr::hdda_ray_clip(blo, bhi, bo, gt0, bd, gt1);
        hits += phit;
        if ((phit != ghit || bits(pt0) != bits(gt0) || bits(pt1) != bits(gt1)) && ++mismatches <= 5) {
            INFO("case " << i);
            CHECK(phit == ghit);
            CHECK(bits(pt0) == bits(gt0));
            CHECK(bits(pt1) == bits(gt1));
        }
    }
    MESSAGE("ray_clip: 200000 rays, ", hits, " hits, ", mismatches, " mismatches");
    CHECK(mismatches == 0);
}
