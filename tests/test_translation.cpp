/*
    The Dr.Jit translation (include/nanovdb_drjit/pnanovdb.h) and the fast
    readers (fast_readers.h, stencil.h) against the original PNanoVDB
    (Debian's libnanovdb-dev, compiled here as C), read for read: tile
    addresses, value addresses, levels and value bits must be identical on
    every query coordinate, for every test grid, on every backend. The readers
    are the ones the plugin uses: the loader's plan_readers() decides them and
    nanovdb_drjit::Reader applies the plan, here as in the plugin.

    Backends: scalar (uint32_t) and LLVM always; CUDA only where a GPU and
    libcuda are present, otherwise the CUDA test case is reported as skipped.
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
#include <drjit/jit.h>
#include <drjit-core/jit.h>

#include <doctest/doctest.h>
#include <backends.h>
#include <grids.h>

#include <array>
#include <cstring>
#include <dlfcn.h>
#include <vector>

namespace ndr = nanovdb_drjit;
namespace loader = nanovdb_loader;
namespace dr = drjit;
using nvdb_test::cuda_available;
using nvdb_test::init_backend;
using nvdb_test::jit_coords;

using Coord3 = std::array<int32_t, 3>;

// Per-grid coordinate count for the read-for-read comparisons (>= 10^6)
static constexpr size_t QUERY_COUNT = 1000000;

namespace {

/// A test grid as the 32-bit words that both readers see, built once for
/// the whole test program, with the reader plan the plugin would use
struct TestGrid {
    std::string name;
    std::vector<uint32_t> words;
    std::vector<Coord3> coords;
    loader::ReaderPlan plan;   ///< plan_readers() of the validated grid
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
            g.plan = loader::plan_readers(
                loader::validate_grid(name, g.words.data(), handle.size()));
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
 * the backend selected by UInt32 (JIT array, or a host pointer for scalars):
 * the plugin's path (the loader's plan, applied by nanovdb_drjit::Reader), or
 * the same plan with the fast readers off.
 */
template <typename UInt32, typename Fn>
void with_reader(const TestGrid &g, Reader reader, Fn &&fn) {
    using Buffer = std::conditional_t<dr::is_jit_v<UInt32>, UInt32, const uint32_t *>;
    Buffer buf;
    if constexpr (dr::is_jit_v<UInt32>)
        buf = dr::load<UInt32>(g.words.data(), g.words.size());
    else
        buf = g.words.data();
    auto r = ndr::Reader<UInt32>::from_plan(reader == Reader::Fast ? g.plan : g.plan.faithful());
    r.apply(buf, fn);
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
          NVDB_CUDA_CASE_SKIP) {
#if NVDB_TEST_CUDA
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
#endif
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

namespace {

/// The same grid with its leaf array moved in front of its lower-node array
/// and every child offset rewritten: valid, but not in NanoVDB's canonical order
TestGrid leaves_before_lower_nodes(const TestGrid &src) {
    namespace L = ndr::layout;
    const L::GridTypeConstants &c = L::GRID_TYPE_CONSTANTS_FLOAT;
    TestGrid g = src;
    g.name = src.name + "_leaves_first";
    const uint8_t *in = reinterpret_cast<const uint8_t *>(src.words.data());
    uint8_t *out = reinterpret_cast<uint8_t *>(g.words.data());
    auto u64 = [](const uint8_t *p) { uint64_t v; std::memcpy(&v, p, 8); return v; };
    auto u32 = [](const uint8_t *p) { uint32_t v; std::memcpy(&v, p, 4); return v; };
    auto put64 = [](uint8_t *p, int64_t v) { std::memcpy(p, &v, 8); };
    const uint64_t tree = L::GRID_SIZE;
    const uint64_t upper = tree + u64(in + tree + L::TREE_OFF_NODE_OFFSET_UPPER),
                   lower = tree + u64(in + tree + L::TREE_OFF_NODE_OFFSET_LOWER),
                   leaf = tree + u64(in + tree + L::TREE_OFF_NODE_OFFSET_LEAF);
    const uint64_t n_upper = u32(in + tree + L::TREE_OFF_NODE_COUNT_UPPER),
                   n_lower = u32(in + tree + L::TREE_OFF_NODE_COUNT_LOWER),
                   n_leaf = u32(in + tree + L::TREE_OFF_NODE_COUNT_LEAF);
    REQUIRE(leaf == lower + n_lower * c.lower_size); // canonical: leaves right after
    const uint64_t new_leaf = lower, new_lower = lower + n_leaf * c.leaf_size;
    std::memcpy(out + new_leaf, in + leaf, n_leaf * c.leaf_size);
    std::memcpy(out + new_lower, in + lower, n_lower * c.lower_size);
    put64(out + tree + L::TREE_OFF_NODE_OFFSET_LEAF, int64_t(new_leaf - tree));
    put64(out + tree + L::TREE_OFF_NODE_OFFSET_LOWER, int64_t(new_lower - tree));
    auto rewrite = [&](uint64_t node_in, uint64_t node_out, uint64_t mask_off, uint64_t table_off,
                       uint64_t count, uint64_t child_begin, uint64_t child_size,
                       uint64_t new_child_begin) {
        for (uint64_t e = 0; e < count; ++e) {
            if (!((u32(in + node_in + mask_off + 4 * (e >> 5)) >> (e & 31)) & 1u))
                continue;
            const uint64_t target = uint64_t(int64_t(node_in) + int64_t(u64(in + node_in + table_off + 8 * e)));
            const uint64_t moved = new_child_begin + (target - child_begin) / child_size * child_size;
            put64(out + node_out + table_off + 8 * e, int64_t(moved) - int64_t(node_out));
        }
    };
    for (uint64_t n = 0; n < n_upper; ++n)
        rewrite(upper + n * c.upper_size, upper + n * c.upper_size, L::UPPER_OFF_CHILD_MASK,
                c.upper_off_table, L::UPPER_TABLE_COUNT, lower, c.lower_size, new_lower);
    for (uint64_t n = 0; n < n_lower; ++n)
        rewrite(lower + n * c.lower_size, new_lower + n * c.lower_size, L::LOWER_OFF_CHILD_MASK,
                c.lower_off_table, L::LOWER_TABLE_COUNT, leaf, c.leaf_size, new_leaf);
    return g;
}

} // namespace

TEST_CASE("the reader policy picks the fast readers for the test grids (so the fast tests test them)") {
    for (const TestGrid &g : test_grids()) {
        INFO("grid ", g.name);
        // NanoVDB writes canonical layouts: every test grid has compact offsets
        CHECK(g.plan.compact_offsets);
        // Only far_coords spans too many 4096^3 blocks for an index
        CHECK(g.plan.root_indexed == (g.name != "far_coords"));
        MESSAGE("grid ", g.name, ": root index ",
                std::string(g.plan.root_indexed ? "yes" : "no (linear search)"), ", ",
                g.plan.root_table.size(), " entries (at most ",
                loader::max_root_index_entries(g.words.size() * 4), ")");
    }
    // A valid layout that is not canonical (leaves stored before the lower
    // nodes, so lower -> leaf offsets are negative) must not get CompactOffsets;
    // its reads through the plan still equal PNanoVDB's algorithm.
    TestGrid g = leaves_before_lower_nodes(test_grids().front());
    loader::ReaderPlan plan = loader::plan_readers(
        loader::validate_grid("reordered", g.words.data(), g.words.size() * 4));
    CHECK_FALSE(plan.compact_offsets);
    CHECK(plan.root_indexed);
    g.plan = plan;
    Reads ref = read_pnanovdb(g);
    compare("scalar fast (non-canonical layout)", g, ref, read_translation<uint32_t>(g, Reader::Fast));
}

TEST_CASE("layout.h: every offset and size equals PNanoVDB's") {
    namespace L = ndr::layout;
    CHECK(L::MAGIC_NUMBER == PNANOVDB_MAGIC_NUMBER);
    CHECK(L::MAJOR_VERSION_NUMBER == PNANOVDB_MAJOR_VERSION_NUMBER);
    CHECK(L::GRID_TYPE_FLOAT == PNANOVDB_GRID_TYPE_FLOAT);
    CHECK(L::MAP_SIZE == PNANOVDB_MAP_SIZE);
    CHECK(L::MAP_OFF_MATD == PNANOVDB_MAP_OFF_MATD);
    CHECK(L::MAP_OFF_INVMATD == PNANOVDB_MAP_OFF_INVMATD);
    CHECK(L::MAP_OFF_VECD == PNANOVDB_MAP_OFF_VECD);
    CHECK(L::GRID_SIZE == PNANOVDB_GRID_SIZE);
    CHECK(L::GRID_OFF_MAGIC == PNANOVDB_GRID_OFF_MAGIC);
    CHECK(L::GRID_OFF_CHECKSUM == PNANOVDB_GRID_OFF_CHECKSUM);
    CHECK(L::GRID_OFF_VERSION == PNANOVDB_GRID_OFF_VERSION);
    CHECK(L::GRID_OFF_GRID_SIZE == PNANOVDB_GRID_OFF_GRID_SIZE);
    CHECK(L::GRID_OFF_GRID_NAME == PNANOVDB_GRID_OFF_GRID_NAME);
    CHECK(L::GRID_OFF_GRID_NAME + L::GRID_NAME_SIZE == PNANOVDB_GRID_OFF_MAP);
    CHECK(L::GRID_OFF_MAP == PNANOVDB_GRID_OFF_MAP);
    CHECK(L::GRID_OFF_VOXEL_SIZE == PNANOVDB_GRID_OFF_VOXEL_SIZE);
    CHECK(L::GRID_OFF_GRID_CLASS == PNANOVDB_GRID_OFF_GRID_CLASS);
    CHECK(L::GRID_OFF_GRID_TYPE == PNANOVDB_GRID_OFF_GRID_TYPE);
    CHECK(L::TREE_SIZE == PNANOVDB_TREE_SIZE);
    CHECK(L::TREE_OFF_NODE_OFFSET_LEAF == PNANOVDB_TREE_OFF_NODE_OFFSET_LEAF);
    CHECK(L::TREE_OFF_NODE_OFFSET_LOWER == PNANOVDB_TREE_OFF_NODE_OFFSET_LOWER);
    CHECK(L::TREE_OFF_NODE_OFFSET_UPPER == PNANOVDB_TREE_OFF_NODE_OFFSET_UPPER);
    CHECK(L::TREE_OFF_NODE_OFFSET_ROOT == PNANOVDB_TREE_OFF_NODE_OFFSET_ROOT);
    CHECK(L::TREE_OFF_NODE_COUNT_LEAF == PNANOVDB_TREE_OFF_NODE_COUNT_LEAF);
    CHECK(L::TREE_OFF_NODE_COUNT_LOWER == PNANOVDB_TREE_OFF_NODE_COUNT_LOWER);
    CHECK(L::TREE_OFF_NODE_COUNT_UPPER == PNANOVDB_TREE_OFF_NODE_COUNT_UPPER);
    CHECK(L::TREE_OFF_VOXEL_COUNT == PNANOVDB_TREE_OFF_VOXEL_COUNT);
    CHECK(L::ROOT_OFF_BBOX_MIN == PNANOVDB_ROOT_OFF_BBOX_MIN);
    CHECK(L::ROOT_OFF_BBOX_MAX == PNANOVDB_ROOT_OFF_BBOX_MAX);
    CHECK(L::ROOT_OFF_TABLE_SIZE == PNANOVDB_ROOT_OFF_TABLE_SIZE);
    CHECK(L::ROOT_TILE_OFF_KEY == PNANOVDB_ROOT_TILE_OFF_KEY);
    CHECK(L::ROOT_TILE_OFF_CHILD == PNANOVDB_ROOT_TILE_OFF_CHILD);
    CHECK(L::ROOT_TILE_OFF_STATE == PNANOVDB_ROOT_TILE_OFF_STATE);
    CHECK(L::UPPER_OFF_BBOX_MIN == PNANOVDB_UPPER_OFF_BBOX_MIN);
    CHECK(L::UPPER_OFF_VALUE_MASK == PNANOVDB_UPPER_OFF_VALUE_MASK);
    CHECK(L::UPPER_OFF_CHILD_MASK == PNANOVDB_UPPER_OFF_CHILD_MASK);
    CHECK(L::LOWER_OFF_BBOX_MIN == PNANOVDB_LOWER_OFF_BBOX_MIN);
    CHECK(L::LOWER_OFF_VALUE_MASK == PNANOVDB_LOWER_OFF_VALUE_MASK);
    CHECK(L::LOWER_OFF_CHILD_MASK == PNANOVDB_LOWER_OFF_CHILD_MASK);
    CHECK(L::LEAF_OFF_BBOX_MIN == PNANOVDB_LEAF_OFF_BBOX_MIN);
    CHECK(L::LEAF_OFF_VALUE_MASK == PNANOVDB_LEAF_OFF_VALUE_MASK);
    CHECK(L::UPPER_TABLE_COUNT == PNANOVDB_UPPER_TABLE_COUNT);
    CHECK(L::LOWER_TABLE_COUNT == PNANOVDB_LOWER_TABLE_COUNT);
    CHECK(L::LEAF_TABLE_COUNT == PNANOVDB_LEAF_TABLE_COUNT);

    // The float row of pnanovdb_grid_type_constants, field by field
    const pnanovdb_grid_type_constants_t &p = pnanovdb_grid_type_constants[PNANOVDB_GRID_TYPE_FLOAT];
    const L::GridTypeConstants &c = *L::grid_type_constants(L::GRID_TYPE_FLOAT);
    static_assert(sizeof(L::GridTypeConstants) == sizeof(pnanovdb_grid_type_constants_t));
    CHECK(std::memcmp(&c, &p, sizeof(p)) == 0);
    CHECK(c.root_size == p.root_size);
    CHECK(c.leaf_size == p.leaf_size);
    CHECK(L::grid_type_constants(PNANOVDB_GRID_TYPE_DOUBLE) == nullptr);

    // Root keys: key_to_block inverts coord_to_key
    for (const Coord3 &ijk : test_grids().front().coords) {
        pnanovdb_coord_t c3 = { ijk[0], ijk[1], ijk[2] };
        int32_t block[3];
        L::key_to_block(pnanovdb_coord_to_key(&c3), block);
        for (int k = 0; k < 3; ++k) {
            // The key keeps 20 bits of each block coordinate (sign-extended back)
            int32_t expect = int32_t(uint32_t(ijk[k] >> 12) << 12) >> 12;
            if (block[k] != expect) {
                INFO("ijk = (", ijk[0], ", ", ijk[1], ", ", ijk[2], "), axis ", k);
                CHECK(block[k] == expect);
            }
        }
    }
}
