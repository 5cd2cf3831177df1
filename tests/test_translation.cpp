/*
    The Dr.Jit translation (include/nanovdb_drjit/pnanovdb.h) against the
    original PNanoVDB (Debian's libnanovdb-dev, compiled here as C), read for
    read: tile addresses, value addresses, levels and value bits must be
    identical on every query coordinate, for every test grid, on every backend.

    Backends: scalar (uint32_t) and LLVM always; CUDA only where a GPU and
    libcuda are present, otherwise the CUDA test case is reported as skipped.
*/

#define PNANOVDB_C
#define PNANOVDB_ADDRESS_64
#include <nanovdb/PNanoVDB.h>

#include <nanovdb_drjit/pnanovdb.h>
#include <drjit/jit.h>
#include <drjit-core/jit.h>

#include <doctest/doctest.h>
#include <grids.h>

#include <array>
#include <cstring>
#include <dlfcn.h>
#include <vector>

namespace ndr = nanovdb_drjit;
namespace dr = drjit;

using Coord3 = std::array<int32_t, 3>;

// Per-grid coordinate count for the read-for-read comparisons (>= 10^6)
static constexpr size_t QUERY_COUNT = 1000000;

namespace {

/// A test grid as the 32-bit words that both readers see
struct TestGrid {
    std::string name;
    std::vector<uint32_t> words;
    std::vector<Coord3> coords;
};

const std::vector<TestGrid> &test_grids() {
    static std::vector<TestGrid> grids = [] {
        std::vector<TestGrid> result;
        uint64_t seed = 1;
        for (const std::string &name : nvdb_test::grid_names()) {
            auto handle = nvdb_test::make_nano_grid(name);
            TestGrid g;
            g.name = name;
            g.words.resize((handle.size() + 3) / 4);
            std::memcpy(g.words.data(), handle.data(), handle.size());
            g.coords = nvdb_test::query_coords(*handle.grid<float>(), QUERY_COUNT, seed++);
            result.push_back(std::move(g));
        }
        return result;
    }();
    return grids;
}

/// What one reader returns for one coordinate
struct Reads {
    std::vector<uint64_t> tile;     // root tile byte address (0: none)
    std::vector<uint64_t> address;  // value byte address
    std::vector<uint32_t> level;
    std::vector<uint32_t> value;    // bits of the float value

    void resize(size_t n) { tile.resize(n); address.resize(n); level.resize(n); value.resize(n); }
};

/// The first n query coordinates of a grid as a JIT coordinate array
template <typename UInt32>
ndr::Coord<UInt32> jit_coords(const std::vector<Coord3> &coords, size_t n) {
    using Int32 = dr::int32_array_t<UInt32>;
    std::vector<int32_t> x(n), y(n), z(n);
    for (size_t i = 0; i < n; ++i) {
        x[i] = coords[i][0]; y[i] = coords[i][1]; z[i] = coords[i][2];
    }
    return { dr::load<Int32>(x.data(), n), dr::load<Int32>(y.data(), n),
             dr::load<Int32>(z.data(), n) };
}

/// Reference: PNanoVDB itself
Reads read_pnanovdb(const TestGrid &g) {
    pnanovdb_buf_t buf;
    buf.data = const_cast<uint32_t *>(g.words.data());
    pnanovdb_grid_handle_t grid = { pnanovdb_address_null() };
    pnanovdb_tree_handle_t tree = pnanovdb_grid_get_tree(buf, grid);
    pnanovdb_root_handle_t root = pnanovdb_tree_get_root(buf, tree);

    Reads r;
    r.resize(g.coords.size());
    for (size_t i = 0; i < g.coords.size(); ++i) {
        pnanovdb_coord_t ijk = { g.coords[i][0], g.coords[i][1], g.coords[i][2] };
        pnanovdb_root_tile_handle_t tile =
            pnanovdb_root_find_tile(PNANOVDB_GRID_TYPE_FLOAT, buf, root, &ijk);
        pnanovdb_uint32_t level = 0;
        pnanovdb_address_t address = pnanovdb_root_get_value_address_and_level(
            PNANOVDB_GRID_TYPE_FLOAT, buf, root, &ijk, &level);
        r.tile[i]    = tile.address.byte_offset;
        r.address[i] = address.byte_offset;
        r.level[i]   = level;
        r.value[i]   = pnanovdb_read_uint32(buf, address);
    }
    return r;
}

/// Which reader the translation is run with
enum class Reader {
    Faithful,   ///< RootHandle + plain buffer: PNanoVDB's algorithm
    Fast        ///< IndexedRootHandle (O(1) root) + CompactOffsets where the grid allows
};

const char *reader_name(Reader r) { return r == Reader::Faithful ? "faithful" : "fast"; }

/**
 * Calls fn(buf, root) with the buffer and root handle of the chosen reader on
 * the backend selected by UInt32 (JIT array, or a host pointer for scalars).
 * The fast reader falls back to the faithful root search or full offsets
 * where the grid does not qualify, as the plugin does.
 */
template <typename UInt32, typename Fn>
void with_reader(const TestGrid &g, Reader reader, Fn &&fn) {
    using Int32 = dr::int32_array_t<UInt32>;
    using Buffer = std::conditional_t<dr::is_jit_v<UInt32>, UInt32, const uint32_t *>;
    Buffer buf;
    if constexpr (dr::is_jit_v<UInt32>)
        buf = dr::load<UInt32>(g.words.data(), g.words.size());
    else
        buf = g.words.data();
    ndr::RootHandle<UInt32> root = ndr::tree_get_root(
        buf, ndr::grid_get_tree(ndr::GridHandle<UInt32>{ dr::opaque<UInt32>(0u) }), true);
    if (reader == Reader::Faithful)
        return fn(buf, root);

    uint32_t root_word = ndr::tree_get_root(g.words.data(),
                                            ndr::grid_get_tree(ndr::GridHandle<uint32_t>{ 0u })).address;
    bool compact = ndr::host::has_compact_offsets(g.words.data(), g.words.size() * 4);
    ndr::host::RootIndex index;
    bool indexed = ndr::host::build_root_index(g.words.data(), root_word, 1u << 20, index);
    if (index.table.empty())
        index.table.push_back(0u);

    auto with_root = [&](const auto &b) {
        if (!indexed)
            return fn(b, root);
        ndr::Coord<UInt32> bmin, bdims;
        for (int k = 0; k < 3; ++k) {
            bmin[k] = dr::opaque<Int32>(index.block_min[k]);
            bdims[k] = dr::opaque<Int32>(index.block_dims[k]);
        }
        if constexpr (dr::is_jit_v<UInt32>) {
            UInt32 table = dr::load<UInt32>(index.table.data(), index.table.size());
            return fn(b, ndr::IndexedRootHandle<UInt32, UInt32>{ root.address, table, bmin, bdims });
        } else {
            return fn(b, ndr::IndexedRootHandle<uint32_t, const uint32_t *>{
                             root.address, index.table.data(), bmin, bdims });
        }
    };
    if (compact)
        with_root(ndr::CompactOffsets<Buffer>{ buf });
    else
        with_root(buf);
}

/// The translation on the backend selected by UInt32
template <typename UInt32> Reads read_translation(const TestGrid &g, Reader reader) {
    size_t n = g.coords.size();
    Reads r;
    r.resize(n);

    with_reader<UInt32>(g, reader, [&](const auto &buf, const auto &root) {
        if constexpr (!dr::is_jit_v<UInt32>) {
            for (size_t i = 0; i < n; ++i) {
                ndr::Coord<uint32_t> ijk(g.coords[i][0], g.coords[i][1], g.coords[i][2]);
                auto tile = ndr::root_find_tile(buf, root, ijk, true);
                auto al = ndr::root_get_value_address_and_level(buf, root, ijk, true);
                r.tile[i]    = uint64_t(tile.address) * 4;
                r.address[i] = uint64_t(al.address) * 4;
                r.level[i]   = al.level;
                r.value[i]   = ndr::read_uint32(buf, al.address, true);
            }
        } else {
            using Mask = dr::mask_t<UInt32>;
            ndr::Coord<UInt32> ijk = jit_coords<UInt32>(g.coords, n);
            Mask active = dr::full<Mask>(true, n);
            auto tile = ndr::root_find_tile(buf, root, ijk, active);
            auto al = ndr::root_get_value_address_and_level(buf, root, ijk, active);
            UInt32 value = ndr::read_uint32(buf, al.address, active);
            UInt32 tile_address = tile.address + dr::zeros<UInt32>(n);
            dr::eval(tile_address, al.address, al.level, value);

            std::vector<uint32_t> t(n), a(n);
            dr::store(t.data(), tile_address);
            dr::store(a.data(), al.address);
            dr::store(r.level.data(), al.level);
            dr::store(r.value.data(), value);
            for (size_t i = 0; i < n; ++i) {
                r.tile[i] = uint64_t(t[i]) * 4;
                r.address[i] = uint64_t(a[i]) * 4;
            }
        }
    });
    return r;
}

/// Compare all reads; report the first few mismatches with their coordinates
void compare(const char *backend, const TestGrid &g, const Reads &ref, const Reads &got) {
    size_t mismatches = 0;
    std::array<size_t, 5> levels{};
    for (size_t i = 0; i < g.coords.size(); ++i) {
        bool same = ref.tile[i] == got.tile[i] && ref.address[i] == got.address[i] &&
                    ref.level[i] == got.level[i] && ref.value[i] == got.value[i];
        if (ref.level[i] < 5)
            levels[ref.level[i]]++;
        if (!same && ++mismatches <= 5) {
            INFO("grid ", g.name, ", ijk = (", g.coords[i][0], ", ", g.coords[i][1], ", ",
                 g.coords[i][2], ")");
            CHECK(ref.tile[i] == got.tile[i]);
            CHECK(ref.address[i] == got.address[i]);
            CHECK(ref.level[i] == got.level[i]);
            CHECK(ref.value[i] == got.value[i]);
        }
    }
    MESSAGE(std::string(backend), ", grid ", g.name, ": ", g.coords.size(), " reads identical to PNanoVDB: ",
            g.coords.size() - mismatches, "; per level (leaf, lower, upper, root tile, "
            "background) = ", levels[0], ", ", levels[1], ", ", levels[2], ", ", levels[3],
            ", ", levels[4]);
    CHECK(g.coords.size() >= QUERY_COUNT);
    CHECK(mismatches == 0);
}

bool cuda_available() {
    static const bool available = dlopen("libcuda.so.1", RTLD_LAZY | RTLD_LOCAL) != nullptr;
    return available;
}

template <typename UInt32> void init_backend() {
    if constexpr (dr::is_jit_v<UInt32>) {
        jit_set_log_level_stderr(LogLevel::Warn);
        jit_init(1u << (uint32_t) dr::backend_v<UInt32>);
    }
}

/// Stencil addresses (8 per coordinate) from the translation's accessor
template <typename UInt32>
std::vector<uint64_t> stencil_translation(const TestGrid &g, Reader reader) {
    size_t n = g.coords.size();
    std::vector<uint64_t> out(8 * n);
    with_reader<UInt32>(g, reader, [&](const auto &buf, const auto &root) {
        if constexpr (!dr::is_jit_v<UInt32>) {
            for (size_t i = 0; i < n; ++i) {
                ndr::Coord<uint32_t> ijk(g.coords[i][0], g.coords[i][1], g.coords[i][2]);
                auto a = ndr::root_get_stencil_addresses(buf, root, ijk, true);
                for (int c = 0; c < 8; ++c)
                    out[8 * i + c] = uint64_t(a[c]) * 4;
            }
        } else {
            using Mask = dr::mask_t<UInt32>;
            ndr::Coord<UInt32> ijk = jit_coords<UInt32>(g.coords, n);
            Mask active = dr::full<Mask>(true, n);
            auto a = ndr::root_get_stencil_addresses(buf, root, ijk, active);
            for (int c = 0; c < 8; ++c)
                dr::eval(a[c]);
            std::vector<uint32_t> tmp(n);
            for (int c = 0; c < 8; ++c) {
                dr::store(tmp.data(), a[c]);
                for (size_t i = 0; i < n; ++i)
                    out[8 * i + c] = uint64_t(tmp[i]) * 4;
            }
        }
    });
    return out;
}

/// Reference: PNanoVDB traverses each of the 8 corners on its own
std::vector<uint64_t> stencil_pnanovdb(const TestGrid &g) {
    pnanovdb_buf_t buf;
    buf.data = const_cast<uint32_t *>(g.words.data());
    pnanovdb_grid_handle_t grid = { pnanovdb_address_null() };
    pnanovdb_root_handle_t root = pnanovdb_tree_get_root(buf, pnanovdb_grid_get_tree(buf, grid));
    std::vector<uint64_t> out(8 * g.coords.size());
    for (size_t i = 0; i < g.coords.size(); ++i)
        for (int c = 0; c < 8; ++c) {
            // + 1 wraps at INT32_MAX as the translation's int32 lanes do;
            // written in uint32 so that it is defined behaviour (UBSan)
            auto plus = [](int32_t v, int b) { return int32_t(uint32_t(v) + uint32_t(b)); };
            pnanovdb_coord_t ijk = { plus(g.coords[i][0], c & 1), plus(g.coords[i][1], (c >> 1) & 1),
                                     plus(g.coords[i][2], (c >> 2) & 1) };
            out[8 * i + c] = pnanovdb_root_get_value_address(PNANOVDB_GRID_TYPE_FLOAT, buf,
                                                             root, &ijk).byte_offset;
        }
    return out;
}

} // namespace

TEST_CASE_TEMPLATE("trilinear stencil accessor: 8 addresses equal 8 PNanoVDB traversals", UInt32,
                   uint32_t, dr::LLVMArray<uint32_t>) {
    init_backend<UInt32>();
    for (const TestGrid &g : test_grids()) {
        SUBCASE(g.name.c_str()) {
            // Query points near INT32_MAX would wrap when +1 is added: PNanoVDB
            // and the accessor wrap alike (int32 arithmetic), so keep them.
          std::vector<uint64_t> ref = stencil_pnanovdb(g);
          for (Reader reader : { Reader::Faithful, Reader::Fast }) {
            std::vector<uint64_t> got = stencil_translation<UInt32>(g, reader);
            size_t mismatches = 0;
            for (size_t i = 0; i < ref.size(); ++i) {
                if (ref[i] != got[i] && ++mismatches <= 5) {
                    const Coord3 &c = g.coords[i / 8];
                    INFO("grid ", g.name, ", ijk0 = (", c[0], ", ", c[1], ", ", c[2],
                         "), corner ", i % 8);
                    CHECK(ref[i] == got[i]);
                }
            }
            MESSAGE(std::string(dr::is_jit_v<UInt32> ? "LLVM" : "scalar"), " ",
                    std::string(reader_name(reader)), ", grid ", g.name, ": ", ref.size(),
                    " stencil addresses, ", mismatches, " mismatches");
            CHECK(mismatches == 0);
          }
        }
    }
}

namespace {
} // namespace

// ---------------------------------------------------------------------------

TEST_CASE("coord_to_key and the node offset functions match PNanoVDB") {
    const TestGrid &g = test_grids().front();
    size_t mismatches = 0;
    for (const Coord3 &c : g.coords) {
        pnanovdb_coord_t ijk = { c[0], c[1], c[2] };
        ndr::Coord<uint32_t> ijk2(c[0], c[1], c[2]);
        auto [kx, ky] = ndr::coord_to_key(ijk2);
        uint64_t key = pnanovdb_coord_to_key(&ijk);
        bool same = (uint64_t(ky) << 32 | kx) == key &&
                    ndr::upper_coord_to_offset(ijk2) == pnanovdb_upper_coord_to_offset(&ijk) &&
                    ndr::lower_coord_to_offset(ijk2) == pnanovdb_lower_coord_to_offset(&ijk) &&
                    ndr::leaf_coord_to_offset(ijk2) == pnanovdb_leaf_coord_to_offset(&ijk);
        if (!same && ++mismatches <= 5) {
            INFO("ijk = (", c[0], ", ", c[1], ", ", c[2], ")");
            CHECK((uint64_t(ky) << 32 | kx) == key);
        }
    }
    CHECK(mismatches == 0);
}

TEST_CASE("grid_get_tree and tree_get_root match PNanoVDB") {
    for (const TestGrid &g : test_grids()) {
        INFO("grid ", g.name);
        pnanovdb_buf_t buf;
        buf.data = const_cast<uint32_t *>(g.words.data());
        pnanovdb_grid_handle_t grid = { pnanovdb_address_null() };
        pnanovdb_tree_handle_t tree = pnanovdb_grid_get_tree(buf, grid);
        pnanovdb_root_handle_t root = pnanovdb_tree_get_root(buf, tree);

        auto tree2 = ndr::grid_get_tree(ndr::GridHandle<uint32_t>{ 0u });
        auto root2 = ndr::tree_get_root(g.words.data(), tree2);
        CHECK(uint64_t(tree2.address) * 4 == tree.address.byte_offset);
        CHECK(uint64_t(root2.address) * 4 == root.address.byte_offset);
        CHECK(ndr::root_get_tile_count(g.words.data(), root2, true) ==
              pnanovdb_root_get_tile_count(buf, root));
    }
}

TEST_CASE_TEMPLATE("root tile, value address, level and value match PNanoVDB", UInt32,
                   uint32_t, dr::LLVMArray<uint32_t>) {
    init_backend<UInt32>();
    for (const TestGrid &g : test_grids()) {
        SUBCASE(g.name.c_str()) {
            Reads ref = read_pnanovdb(g);
            for (Reader reader : { Reader::Faithful, Reader::Fast })
                compare((std::string(dr::is_jit_v<UInt32> ? "LLVM " : "scalar ") +
                         reader_name(reader)).c_str(),
                        g, ref, read_translation<UInt32>(g, reader));
        }
    }
}

TEST_CASE("CUDA: root tile, value address, level and value match PNanoVDB" *
          doctest::skip(!cuda_available())) {
    init_backend<dr::CUDAArray<uint32_t>>();
    REQUIRE(jit_has_backend(JitBackend::CUDA));
    for (const TestGrid &g : test_grids()) {
        SUBCASE(g.name.c_str()) {
            Reads ref = read_pnanovdb(g);
            for (Reader reader : { Reader::Faithful, Reader::Fast })
                compare((std::string("CUDA ") + reader_name(reader)).c_str(), g, ref,
                        read_translation<dr::CUDAArray<uint32_t>>(g, reader));
        }
    }
}

TEST_CASE("inactive lanes never read: a corrupt child offset behind a false mask is harmless") {
    init_backend<dr::LLVMArray<uint32_t>>();
    using UInt32 = dr::LLVMArray<uint32_t>;
    using Mask = dr::LLVMArray<bool>;

    // Take a grid with a root tile child, point every root tile's child far
    // outside the buffer, and query it with all lanes but one inactive.
    TestGrid g = test_grids().front();
    auto root = ndr::tree_get_root(g.words.data(), ndr::grid_get_tree(ndr::GridHandle<uint32_t>{ 0u }));
    uint32_t tiles = ndr::root_get_tile_count(g.words.data(), root, true);
    REQUIRE(tiles > 0);
    for (uint32_t t = 0; t < tiles; ++t) {
        uint32_t tile = ndr::root_get_tile(root, t).address;
        g.words[tile + 2] = 0x7ffffff0u; // child offset low word: ~8 GiB away
        g.words[tile + 3] = 0u;
    }
    size_t n = 4096;
    UInt32 buf = dr::load<UInt32>(g.words.data(), g.words.size());
    ndr::Coord<UInt32> ijk = jit_coords<UInt32>(g.coords, n);
    Mask active = dr::full<Mask>(false, n);
    auto al = ndr::root_get_value_address_and_level(buf, ndr::RootHandle<UInt32>{ root.address },
                                                    ijk, active);
    UInt32 value = ndr::read_uint32(buf, al.address, active);
    dr::eval(value);
    std::vector<uint32_t> out(n);
    dr::store(out.data(), value);
    size_t nonzero = 0;
    for (uint32_t v : out)
        nonzero += v != 0;
    CHECK(nonzero == 0);
}

TEST_CASE("the fast readers apply to the test grids (so the fast tests test them)") {
    for (const TestGrid &g : test_grids()) {
        INFO("grid ", g.name);
        uint32_t root_word = ndr::tree_get_root(g.words.data(),
                                                ndr::grid_get_tree(ndr::GridHandle<uint32_t>{ 0u })).address;
        ndr::host::RootIndex index;
        bool indexed = ndr::host::build_root_index(g.words.data(), root_word, 1u << 20, index);
        // NanoVDB writes canonical layouts: every test grid has compact offsets
        CHECK(ndr::host::has_compact_offsets(g.words.data(), g.words.size() * 4));
        // Only far_coords spans too many 4096^3 blocks for an index
        CHECK(indexed == (g.name != "far_coords"));
        MESSAGE("grid ", g.name, ": root index ", std::string(indexed ? "yes" : "no (linear search)"),
                ", ", index.table.size(), " entries");
    }
    // A layout that is not canonical is detected: swap the lower and leaf arrays' order
    TestGrid g = test_grids().front();
    uint32_t tree = ndr::words(ndr::GRID_SIZE);
    std::swap(g.words[tree + 0], g.words[tree + 2]);   // leaf offset <-> lower offset (low words)
    CHECK_FALSE(ndr::host::has_compact_offsets(g.words.data(), g.words.size() * 4));
}
