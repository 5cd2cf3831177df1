/*
    The value types beyond float (Half, Fp4, Fp8, Fp16, FpN) against the
    original PNanoVDB and NanoVDB's own C++ accessor, read for read:

      - half -> float: pnanovdb.h's half_to_float (scalar and LLVM) and the
        loader's host conversion against the CPU's F16C instruction, over all
        65,536 halves; the loader's float -> half against F16C on every half,
        every tie between two halves and 10^7 random floats;
      - per test grid and type: value address, level and value bits of the
        translation (scalar, LLVM; the faithful and the plugin's fast readers)
        against PNanoVDB's per-type readers (pnanovdb_root_fp*_read_float,
        pnanovdb_read_half converted by F16C) on >= 10^6 coordinates, and the
        values against NanoVDB's accessor (NanoGrid<Fp4>, ...; Half: the float
        grid's value rounded by F16C);
      - the trilinear stencil's 8 values against 8 traversals.

    Compiled with -ffp-contract=off (as the whole project): a quantized value
    is float(code) * quantum + minimum, rounded the same way everywhere.
*/

#define PNANOVDB_C
#define PNANOVDB_ADDRESS_64
#include <nanovdb/PNanoVDB.h>

#include <nanovdb_drjit/fast_readers.h>
#include <nanovdb_drjit/layout.h>
#include <nanovdb_drjit/pnanovdb.h>
#include <nanovdb_drjit/stencil.h>
#include <nanovdb_loader/reader_policy.h>
#include <nanovdb_loader/validation.h>
#include "../src/loader/value_codec.h"
#include <drjit/jit.h>
#include <drjit-core/jit.h>

#include <doctest/doctest.h>
#include <backends.h>
#include <typed_grids.h>

#include <array>
#include <cstring>
#include <dlfcn.h>
#include <map>
#include <memory>
#include <vector>

namespace ndr = nanovdb_drjit;
namespace loader = nanovdb_loader;
namespace dr = drjit;
using nvdb_test::cuda_available;
using nvdb_test::init_backend;
using nvdb_test::jit_coords;

using Coord3 = std::array<int32_t, 3>;
static constexpr size_t QUERY_COUNT = 1000000;
static constexpr size_t STENCIL_COUNT = 100000;

namespace {

uint32_t bits_of(float f) {
    uint32_t b;
    std::memcpy(&b, &f, 4);
    return b;
}

/// A typed grid with its validation, reader plan and query coordinates
struct Case {
    nvdb_test::TypedGrid grid;
    loader::ReaderPlan plan;
    std::vector<Coord3> coords;
    std::string label() const { return grid.name + " (" + grid.type + ")"; }
};

const std::vector<std::unique_ptr<Case>> &cases() {
    static std::vector<std::unique_ptr<Case>> all = [] {
        std::vector<std::unique_ptr<Case>> out;
        uint64_t seed = 100;
        for (const std::string &name : nvdb_test::grid_names()) {
            for (const char *type : { "fp4", "fp8", "fp16", "fpn", "half" }) {
                if (!nvdb_test::has_typed_grid(name, type))
                    continue; // FpN without leaves: NanoVDB cannot write it
                auto c = std::make_unique<Case>();
                c->grid = nvdb_test::make_typed_grid(name, type);
                c->plan = loader::plan_readers(loader::validate_grid(
                    c->label(), c->grid.words.data(), c->grid.bytes));
                c->coords = nvdb_test::query_coords(*c->grid.float_grid.grid<float>(),
                                                    QUERY_COUNT, seed++);
                out.push_back(std::move(c));
            }
        }
        return out;
    }();
    return all;
}

struct Reads {
    std::vector<uint64_t> address; ///< byte address of the word holding the value
    std::vector<uint32_t> level, value;
};

/// PNanoVDB's reads: the type's reader at the address and level
Reads read_pnanovdb(const Case &c) {
    pnanovdb_buf_t buf;
    buf.data = const_cast<uint32_t *>(c.grid.words.data());
    pnanovdb_grid_handle_t grid = { pnanovdb_address_null() };
    pnanovdb_root_handle_t root = pnanovdb_tree_get_root(buf, pnanovdb_grid_get_tree(buf, grid));
    const pnanovdb_grid_type_t type = c.grid.grid_type;
    Reads r;
    const size_t n = c.coords.size();
    r.address.resize(n); r.level.resize(n); r.value.resize(n);
    for (size_t i = 0; i < n; ++i) {
        pnanovdb_coord_t ijk = { c.coords[i][0], c.coords[i][1], c.coords[i][2] };
        pnanovdb_uint32_t level = 0;
        pnanovdb_address_t a =
            pnanovdb_root_get_value_address_and_level(type, buf, root, &ijk, &level);
        float v = 0.f;
        switch (type) {
            case PNANOVDB_GRID_TYPE_FP4: v = pnanovdb_root_fp4_read_float(buf, a, &ijk, level); break;
            case PNANOVDB_GRID_TYPE_FP8: v = pnanovdb_root_fp8_read_float(buf, a, &ijk, level); break;
            case PNANOVDB_GRID_TYPE_FP16: v = pnanovdb_root_fp16_read_float(buf, a, &ijk, level); break;
            case PNANOVDB_GRID_TYPE_FPN: v = pnanovdb_root_fpn_read_float(buf, a, &ijk, level); break;
            default: v = nvdb_test::f16c_to_float(uint16_t(pnanovdb_read_half(buf, a))); break;
        }
        r.address[i] = a.byte_offset & ~uint64_t(3);
        r.level[i] = level;
        r.value[i] = bits_of(v);
    }
    return r;
}

template <typename UInt32, typename Fn> void with_reader(const Case &c, bool fast, Fn &&fn) {
    using Buffer = std::conditional_t<dr::is_jit_v<UInt32>, UInt32, const uint32_t *>;
    Buffer buf;
    if constexpr (dr::is_jit_v<UInt32>)
        buf = dr::load<UInt32>(c.grid.words.data(), c.grid.words.size());
    else
        buf = c.grid.words.data();
    ndr::Reader<UInt32>::from_plan(fast ? c.plan : c.plan.faithful()).apply(buf, fn);
}

/// The translation's reads, for grid type T
template <uint32_t T, typename UInt32> Reads read_translation(const Case &c, bool fast) {
    const size_t n = c.coords.size();
    Reads r;
    r.address.resize(n); r.level.resize(n); r.value.resize(n);
    with_reader<UInt32>(c, fast, [&](const auto &buf, const auto &root) {
        if constexpr (!dr::is_jit_v<UInt32>) {
            for (size_t i = 0; i < n; ++i) {
                ndr::Coord<uint32_t> ijk(c.coords[i][0], c.coords[i][1], c.coords[i][2]);
                auto al = ndr::root_get_value_address_and_level<T>(buf, root, ijk, true);
                r.address[i] = uint64_t(al.address) * 4;
                r.level[i] = al.level;
                r.value[i] = bits_of(ndr::root_read_float<T>(buf, al.address, al.level, ijk, true));
            }
        } else {
            using Mask = dr::mask_t<UInt32>;
            ndr::Coord<UInt32> ijk = jit_coords<UInt32>(c.coords, n);
            Mask active = dr::full<Mask>(true, n);
            auto al = ndr::root_get_value_address_and_level<T>(buf, root, ijk, active);
            UInt32 value = dr::reinterpret_array<UInt32>(
                ndr::root_read_float<T>(buf, al.address, al.level, ijk, active));
            dr::eval(al.address, al.level, value);
            std::vector<uint32_t> a(n);
            dr::store(a.data(), al.address);
            dr::store(r.level.data(), al.level);
            dr::store(r.value.data(), value);
            for (size_t i = 0; i < n; ++i)
                r.address[i] = uint64_t(a[i]) * 4;
        }
    });
    return r;
}

/// The scalar types (Vec3f has its own test case below)
template <typename Fn> decltype(auto) with_type(uint32_t grid_type, Fn &&fn) {
    return ndr::layout::visit_value_type<false>(grid_type, std::forward<Fn>(fn));
}

} // namespace

// ---------------------------------------------------------------------------

TEST_CASE_TEMPLATE("half -> float: all 65,536 halves as F16C converts them", UInt32, uint32_t,
                   dr::LLVMArray<uint32_t>) {
    init_backend<UInt32>();
    std::vector<uint32_t> ref(65536), got(65536), host(65536);
    for (uint32_t h = 0; h < 65536; ++h) {
        ref[h] = bits_of(nvdb_test::f16c_to_float(uint16_t(h)));
        host[h] = bits_of(loader::detail::half_to_float(uint16_t(h)));
    }
    if constexpr (dr::is_jit_v<UInt32>) {
        UInt32 h = dr::arange<UInt32>(65536);
        UInt32 f = dr::reinterpret_array<UInt32>(ndr::half_to_float(h));
        dr::eval(f);
        dr::store(got.data(), f);
    } else {
        for (uint32_t h = 0; h < 65536; ++h)
            got[h] = bits_of(ndr::half_to_float(h));
    }
    size_t device_mismatch = 0, host_mismatch = 0;
    for (uint32_t h = 0; h < 65536; ++h) {
        if (got[h] != ref[h] && ++device_mismatch <= 5) {
            INFO("half 0x", std::hex, h);
            CHECK(got[h] == ref[h]);
        }
        if (host[h] != ref[h] && ++host_mismatch <= 5) {
            INFO("host, half 0x", std::hex, h);
            CHECK(host[h] == ref[h]);
        }
    }
    MESSAGE(std::string(dr::is_jit_v<UInt32> ? "LLVM" : "scalar"), ": 65536 halves, ", device_mismatch,
            " device and ", host_mismatch, " host mismatches against F16C");
    CHECK(device_mismatch == 0);
    CHECK(host_mismatch == 0);
}

TEST_CASE("float -> half (the loader's, for invalid_values=clamp) rounds as F16C") {
    std::vector<float> inputs;
    for (uint32_t h = 0; h < 65536; ++h) {
        const float f = nvdb_test::f16c_to_float(uint16_t(h));
        inputs.push_back(f);
        // The tie halfway to the next half of larger magnitude, and just around it
        const float g = nvdb_test::f16c_to_float(uint16_t(h + 1));
        if ((h & 0x7fff) < 0x7bff) {
            const double mid = (double(f) + double(g)) / 2;
            inputs.push_back(float(mid));
            inputs.push_back(std::nextafter(float(mid), 0.f));
            inputs.push_back(std::nextafter(float(mid), 1e30f * (f < 0 ? -1.f : 1.f)));
        }
    }
    for (float f : { 65504.f, 65519.99f, 65520.f, 1e30f, -1e30f, 5.96e-8f, 2.98e-8f, 2.99e-8f,
                     6.1035156e-5f, 6.1e-5f, 0.f, -0.f })
        inputs.push_back(f);
    uint64_t state = 12345;
    for (int i = 0; i < 10000000; ++i) {
        state = state * 6364136223846793005ull + 1442695040888963407ull;
        uint32_t b = uint32_t(state >> 32);
        float f;
        std::memcpy(&f, &b, 4);
        inputs.push_back(f);
    }
    size_t mismatches = 0;
    for (float f : inputs) {
        const uint16_t ref = nvdb_test::f16c_from_float(f), got = loader::detail::float_to_half(f);
        // NaN: any NaN with the sign (F16C keeps the payload's top bits)
        const bool same = std::isnan(f) ? ((got & 0x7c00) == 0x7c00 && (got & 0x3ff) != 0 &&
                                           (got & 0x8000) == (ref & 0x8000))
                                        : got == ref;
        if (!same && ++mismatches <= 5) {
            INFO("float ", f, " (bits 0x", std::hex, bits_of(f), ")");
            CHECK(got == ref);
        }
    }
    MESSAGE(inputs.size(), " floats, ", mismatches, " mismatches against F16C");
    CHECK(mismatches == 0);
}

/// Reads of every typed grid on the backend of UInt32 against PNanoVDB's
template <typename UInt32> void check_typed_reads() {
    init_backend<UInt32>();
    for (const auto &cp : cases()) {
        const Case &c = *cp;
        SUBCASE(c.label().c_str()) {
            const Reads ref = read_pnanovdb(c);
            for (bool fast : { false, true }) {
                const Reads got = with_type(c.grid.grid_type, [&](auto t) {
                    return read_translation<decltype(t)::value, UInt32>(c, fast);
                });
                size_t mismatches = 0;
                std::array<size_t, 5> levels{};
                for (size_t i = 0; i < c.coords.size(); ++i) {
                    levels[std::min<uint32_t>(ref.level[i], 4)]++;
                    const bool same = ref.address[i] == got.address[i] &&
                                      ref.level[i] == got.level[i] && ref.value[i] == got.value[i];
                    if (!same && ++mismatches <= 5) {
                        INFO(c.label(), ", ijk = (", c.coords[i][0], ", ", c.coords[i][1], ", ",
                             c.coords[i][2], ")");
                        CHECK(ref.address[i] == got.address[i]);
                        CHECK(ref.level[i] == got.level[i]);
                        CHECK(ref.value[i] == got.value[i]);
                    }
                }
                MESSAGE(std::string(!dr::is_jit_v<UInt32> ? "scalar "
                                    : dr::backend_v<UInt32> == JitBackend::CUDA ? "CUDA " : "LLVM "),
                        std::string(fast ? "fast" : "faithful"),
                        ", ", c.label(), ": ", c.coords.size() - mismatches, " of ",
                        c.coords.size(), " reads identical to PNanoVDB; per level (leaf, lower, "
                        "upper, root tile, background) = ", levels[0], ", ", levels[1], ", ",
                        levels[2], ", ", levels[3], ", ", levels[4]);
                CHECK(c.coords.size() >= QUERY_COUNT);
                CHECK(mismatches == 0);
                // every grid but "empty" has leaves, and the coordinates reach them
                CHECK((levels[0] > 0) == (c.grid.float_grid.grid<float>()->tree().nodeCount(0) > 0));
            }
        }
    }
}

TEST_CASE_TEMPLATE("typed grids: address, level and value equal PNanoVDB's per-type readers",
                   UInt32, uint32_t, dr::LLVMArray<uint32_t>) {
    check_typed_reads<UInt32>();
}

TEST_CASE("CUDA: typed grids' reads equal PNanoVDB's" * NVDB_CUDA_CASE_SKIP) {
#if NVDB_TEST_CUDA
    check_typed_reads<dr::CUDAArray<uint32_t>>();
#endif
}

TEST_CASE("typed grids: values equal NanoVDB's accessor (Half: F16C of the float grid)") {
    for (const auto &cp : cases()) {
        const Case &c = *cp;
        SUBCASE(c.label().c_str()) {
            const Reads got = with_type(c.grid.grid_type, [&](auto t) {
                return read_translation<decltype(t)::value, uint32_t>(c, true);
            });
            auto reference = c.grid.reference();
            size_t mismatches = 0;
            for (size_t i = 0; i < c.coords.size(); ++i) {
                const uint32_t ref =
                    bits_of(reference(nanovdb::Coord(c.coords[i][0], c.coords[i][1], c.coords[i][2])));
                if (ref != got.value[i] && ++mismatches <= 5) {
                    INFO(c.label(), ", ijk = (", c.coords[i][0], ", ", c.coords[i][1], ", ",
                         c.coords[i][2], ")");
                    CHECK(ref == got.value[i]);
                }
            }
            MESSAGE(c.label(), ": ", c.coords.size(), " values, ", mismatches,
                    " mismatches against NanoVDB's accessor");
            CHECK(mismatches == 0);
        }
    }
}

TEST_CASE_TEMPLATE("typed grids: the stencil's 8 values equal 8 traversals", UInt32, uint32_t,
                   dr::LLVMArray<uint32_t>) {
    init_backend<UInt32>();
    for (const auto &cp : cases()) {
        const Case &c = *cp;
        SUBCASE(c.label().c_str()) {
            const size_t n = STENCIL_COUNT;
            std::vector<uint32_t> via_stencil(8 * n), via_traversal(8 * n);
            with_type(c.grid.grid_type, [&](auto t) {
                constexpr uint32_t T = decltype(t)::value;
                with_reader<UInt32>(c, true, [&](const auto &buf, const auto &root) {
                    if constexpr (!dr::is_jit_v<UInt32>) {
                        for (size_t i = 0; i < n; ++i) {
                            ndr::Coord<uint32_t> ijk0(c.coords[i][0], c.coords[i][1], c.coords[i][2]);
                            auto s = ndr::root_get_stencil<T, true>(buf, root, ijk0, true);
                            for (uint32_t k = 0; k < 8; ++k) {
                                auto ijk = ndr::coord_add<uint32_t>(ijk0, k & 1u, (k >> 1) & 1u, (k >> 2) & 1u);
                                via_stencil[8 * i + k] = bits_of(
                                    ndr::root_read_float<T>(buf, s.address[k], s.level[k], ijk, true));
                                via_traversal[8 * i + k] =
                                    bits_of(ndr::root_get_value<T>(buf, root, ijk, true));
                            }
                        }
                    } else {
                        using Mask = dr::mask_t<UInt32>;
                        using Float = dr::float32_array_t<UInt32>;
                        // One lane per (point, corner): lane 8 i + k reads corner k of
                        // point i, so that the kernel holds one stencil, one read and
                        // one traversal (8 unrolled corners compile 4x longer)
                        using Int32 = dr::int32_array_t<UInt32>;
                        std::vector<Coord3> repeated(8 * n);
                        for (size_t i = 0; i < 8 * n; ++i)
                            repeated[i] = c.coords[i / 8];
                        ndr::Coord<UInt32> ijk0 = jit_coords<UInt32>(repeated, 8 * n);
                        UInt32 k = dr::arange<UInt32>(8 * n) & 7u;
                        Mask active = dr::full<Mask>(true, 8 * n);
                        auto s = ndr::root_get_stencil<T, true>(buf, root, ijk0, active);
                        UInt32 address = s.address[0], level = s.level[0];
                        for (uint32_t j = 1; j < 8; ++j) {
                            address = dr::select(k == j, s.address[j], address);
                            level = dr::select(k == j, s.level[j], level);
                        }
                        auto offset = [&](const Int32 &v, uint32_t bit) {
                            return dr::reinterpret_array<Int32>(
                                dr::reinterpret_array<UInt32>(v) + ((k >> bit) & 1u));
                        };
                        ndr::Coord<UInt32> ijk(offset(ijk0.x(), 0), offset(ijk0.y(), 1),
                                               offset(ijk0.z(), 2));
                        Float x = ndr::root_read_float<T>(buf, address, level, ijk, active),
                              y = ndr::root_get_value<T>(buf, root, ijk, active);
                        dr::eval(x, y);
                        dr::store(via_stencil.data(), dr::reinterpret_array<UInt32>(x));
                        dr::store(via_traversal.data(), dr::reinterpret_array<UInt32>(y));
                    }
                });
            });
            size_t mismatches = 0;
            for (size_t i = 0; i < 8 * n; ++i)
                if (via_stencil[i] != via_traversal[i] && ++mismatches <= 5) {
                    const Coord3 &q = c.coords[i / 8];
                    INFO(c.label(), ", ijk0 = (", q[0], ", ", q[1], ", ", q[2], "), corner ", i % 8);
                    CHECK(via_stencil[i] == via_traversal[i]);
                }
            MESSAGE(std::string(dr::is_jit_v<UInt32> ? "LLVM" : "scalar"), ", ", c.label(), ": ", 8 * n,
                    " stencil values, ", mismatches, " mismatches");
            CHECK(mismatches == 0);
        }
    }
}

// ---------------------------------------------------------------------------
//  Vec3f
// ---------------------------------------------------------------------------

TEST_CASE_TEMPLATE("Vec3f grids: address, level and 3 floats equal PNanoVDB's reads and "
                   "NanoVDB's accessor", UInt32, uint32_t, dr::LLVMArray<uint32_t>) {
    init_backend<UInt32>();
    constexpr uint32_t T = ndr::layout::GRID_TYPE_VEC3F;
    uint64_t seed = 500;
    for (const std::string &name : nvdb_test::grid_names()) {
        SUBCASE(name.c_str()) {
            Case c;
            c.grid = nvdb_test::make_typed_grid(name, "vec3f");
            c.plan = loader::plan_readers(
                loader::validate_grid(c.label(), c.grid.words.data(), c.grid.bytes));
            c.coords = nvdb_test::query_coords(*c.grid.float_grid.grid<float>(), QUERY_COUNT, seed++);
            const size_t n = c.coords.size();
            // PNanoVDB: address and level, then three floats
            pnanovdb_buf_t pbuf;
            pbuf.data = c.grid.words.data();
            pnanovdb_grid_handle_t pgrid = { pnanovdb_address_null() };
            pnanovdb_root_handle_t proot =
                pnanovdb_tree_get_root(pbuf, pnanovdb_grid_get_tree(pbuf, pgrid));
            std::vector<uint64_t> ref_address(n);
            std::vector<uint32_t> ref_level(n), ref_value(3 * n), acc_value(3 * n);
            auto reference = c.grid.reference3();
            for (size_t i = 0; i < n; ++i) {
                pnanovdb_coord_t ijk = { c.coords[i][0], c.coords[i][1], c.coords[i][2] };
                pnanovdb_uint32_t level = 0;
                pnanovdb_address_t a = pnanovdb_root_get_value_address_and_level(
                    PNANOVDB_GRID_TYPE_VEC3F, pbuf, proot, &ijk, &level);
                ref_address[i] = a.byte_offset;
                ref_level[i] = level;
                float acc[3];
                reference(nanovdb::Coord(ijk.x, ijk.y, ijk.z), acc);
                for (uint32_t k = 0; k < 3; ++k) {
                    ref_value[3 * i + k] =
                        bits_of(pnanovdb_read_float(pbuf, pnanovdb_address_offset(a, 4 * k)));
                    acc_value[3 * i + k] = bits_of(acc[k]);
                }
            }
            for (bool fast : { false, true }) {
                std::vector<uint64_t> address(n);
                std::vector<uint32_t> level(n), value(3 * n);
                with_reader<UInt32>(c, fast, [&](const auto &buf, const auto &root) {
                    if constexpr (!dr::is_jit_v<UInt32>) {
                        for (size_t i = 0; i < n; ++i) {
                            ndr::Coord<uint32_t> ijk(c.coords[i][0], c.coords[i][1], c.coords[i][2]);
                            auto al = ndr::root_get_value_address_and_level<T>(buf, root, ijk, true);
                            auto v = ndr::root_read_vec3f<T>(buf, al.address, true);
                            address[i] = uint64_t(al.address) * 4;
                            level[i] = al.level;
                            for (int k = 0; k < 3; ++k)
                                value[3 * i + k] = bits_of(v[k]);
                        }
                    } else {
                        using Mask = dr::mask_t<UInt32>;
                        ndr::Coord<UInt32> ijk = jit_coords<UInt32>(c.coords, n);
                        Mask active = dr::full<Mask>(true, n);
                        auto al = ndr::root_get_value_address_and_level<T>(buf, root, ijk, active);
                        auto v = ndr::root_read_vec3f<T>(buf, al.address, active);
                        dr::eval(al.address, al.level, v);
                        std::vector<uint32_t> a(n), ch(n);
                        dr::store(a.data(), al.address);
                        dr::store(level.data(), al.level);
                        for (size_t i = 0; i < n; ++i)
                            address[i] = uint64_t(a[i]) * 4;
                        for (int k = 0; k < 3; ++k) {
                            dr::store(ch.data(), dr::reinterpret_array<UInt32>(v[k]));
                            for (size_t i = 0; i < n; ++i)
                                value[3 * i + k] = ch[i];
                        }
                    }
                });
                size_t mismatches = 0, accessor_mismatches = 0;
                for (size_t i = 0; i < n; ++i) {
                    bool same = address[i] == ref_address[i] && level[i] == ref_level[i];
                    bool same_acc = true;
                    for (int k = 0; k < 3; ++k) {
                        same &= value[3 * i + k] == ref_value[3 * i + k];
                        same_acc &= value[3 * i + k] == acc_value[3 * i + k];
                    }
                    if (!same && ++mismatches <= 5) {
                        INFO(c.label(), ", ijk = (", c.coords[i][0], ", ", c.coords[i][1], ", ",
                             c.coords[i][2], ")");
                        CHECK(address[i] == ref_address[i]);
                        CHECK(level[i] == ref_level[i]);
                        CHECK(value[3 * i] == ref_value[3 * i]);
                    }
                    if (!same_acc && ++accessor_mismatches <= 5) {
                        INFO(c.label(), " vs NanoVDB's accessor, ijk = (", c.coords[i][0], ", ",
                             c.coords[i][1], ", ", c.coords[i][2], ")");
                        CHECK(value[3 * i] == acc_value[3 * i]);
                    }
                }
                MESSAGE(std::string(dr::is_jit_v<UInt32> ? "LLVM " : "scalar "),
                        std::string(fast ? "fast" : "faithful"), ", ", c.label(), ": ",
                        n - mismatches, " of ", n, " reads identical to PNanoVDB, ",
                        n - accessor_mismatches, " to NanoVDB's accessor");
                CHECK(n >= QUERY_COUNT);
                CHECK(mismatches == 0);
                CHECK(accessor_mismatches == 0);
            }
        }
    }
}
