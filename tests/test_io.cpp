// Tests of include/nanovdb_drjit/io.h, the host-side .nvdb loader.
//
// The independent references are NanoVDB 32.4's own C++ API (Debian's
// libnanovdb-dev): its writer (nanovdb::io::writeGrid/writeGrids with the
// NONE, ZIP and BLOSC codecs), its reader (nanovdb::io::readGrid), its grid
// builders and its node structs, plus OpenVDB 10 for grids with tiles at
// every level. Newer file forms (32.6+ raw grid buffers, 32.8+ "NanoVDB2" /
// "NanoVDB1" magics) are hand-built from files the 32.4 writer made. Hostile
// inputs are made by patching such files at offsets located with the NanoVDB
// API. The real files in ../shared/data are read in place.

#include <doctest/doctest.h>

#include <nanovdb/NanoVDB.h>
#include <nanovdb/util/GridBuilder.h>
#include <nanovdb/util/IO.h>
#include <nanovdb/util/OpenToNanoVDB.h>
#include <nanovdb/util/Primitives.h>
#include <openvdb/openvdb.h>

#include "nanovdb_drjit/io.h"
#include "nanovdb_drjit/pnanovdb.h"

#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <initializer_list>
#include <limits>
#include <memory>
#include <random>
#include <string>
#include <vector>

namespace nio = nanovdb_drjit::io;
namespace fs = std::filesystem;
using Bytes = std::vector<uint8_t>;
using Handle = nanovdb::GridHandle<nanovdb::HostBuffer>;

namespace {

/// The real volumes from other tools: $NVDB_SHARED_DATA, by default
/// ../shared/data beside the repository. Tests that need them are skipped
/// when the folder is absent.
std::string shared_data_dir() {
    const char *env = std::getenv("NVDB_SHARED_DATA");
    return env && *env ? std::string(env) : std::string(NVDB_SHARED_DATA_DIR);
}

// ---- Files and buffers ------------------------------------------------------------

/// A per-process scratch directory, removed at exit.
struct TempDir {
    fs::path dir;
    TempDir() {
        dir = fs::temp_directory_path() / ("nvdb_test_io_" + std::to_string(::getpid()));
        fs::create_directories(dir);
    }
    ~TempDir() {
        std::error_code ec;
        fs::remove_all(dir, ec);
    }
};

std::string tmp_path(const std::string &name) {
    static TempDir tmp;
    return (tmp.dir / name).string();
}

Bytes read_bytes(const std::string &path) {
    std::ifstream in(path, std::ios::binary);
    return Bytes(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void write_bytes(const std::string &path, const Bytes &b) {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char *>(b.data()), std::streamsize(b.size()));
}

template <typename T> void poke(Bytes &b, uint64_t offset, T v) {
    REQUIRE(offset + sizeof(T) <= b.size());
    std::memcpy(b.data() + offset, &v, sizeof(T));
}

template <typename T> T peek(const Bytes &b, uint64_t offset) {
    T v;
    std::memcpy(&v, b.data() + offset, sizeof(T));
    return v;
}

Bytes handle_bytes(const Handle &h) {
    const uint8_t *p = reinterpret_cast<const uint8_t *>(h.data());
    return Bytes(p, p + h.size());
}

/// 32-byte aligned buffer, as the plugin allocates it.
struct Aligned {
    std::unique_ptr<uint8_t, void (*)(void *)> ptr{ nullptr, std::free };
    uint64_t size = 0;
    explicit Aligned(uint64_t n) : size(n) {
        ptr.reset(static_cast<uint8_t *>(std::aligned_alloc(32, (n + 31) / 32 * 32)));
    }
    uint8_t *data() const { return ptr.get(); }
    Bytes bytes() const { return Bytes(data(), data() + size); }
};

Aligned load(const std::string &path, const nio::GridEntry &e) {
    Aligned a(e.grid_size);
    nio::read_grid(path, e, a.data());
    return a;
}

uint32_t packed_version(uint32_t major, uint32_t minor, uint32_t patch) {
    return major << 21 | minor << 10 | patch;
}

// ---- Error checks -------------------------------------------------------------------

std::string error_of(const std::function<void()> &f) {
    try {
        f();
    } catch (const nio::Error &e) {
        return e.what();
    } catch (const std::exception &e) {
        return std::string("<wrong exception type, not io::Error> ") + e.what();
    }
    return "<no exception>";
}

void check_message(const std::string &msg, const std::string &path,
                   std::initializer_list<std::string> keys) {
    INFO("message: " << msg);
    CHECK(msg.rfind("\"" + path + "\": ", 0) == 0);
    for (const std::string &k : keys) {
        INFO("expected to contain: " << k);
        CHECK(msg.find(k) != std::string::npos);
    }
}

/// The io::Error thrown by `expr` starts with the quoted path and contains
/// every key word.
#define CHECK_IO_ERROR(expr, path, ...)                                          \
    do {                                                                         \
        INFO("expression: " #expr);                                              \
        check_message(error_of([&] { (void) (expr); }), (path), { __VA_ARGS__ }); \
    } while (0)

// ---- Test grids, built with NanoVDB's / OpenVDB's own APIs --------------------------------

Handle fog_sphere(const std::string &name = "density") {
    return nanovdb::createFogVolumeSphere<float>(12.0f, nanovdb::Vec3f(1, 2, 3), 0.5, 3.0,
                                                 nanovdb::Vec3d(0.25, -1.0, 2.0), name);
}

Handle ls_torus(const std::string &name = "surface") {
    return nanovdb::createLevelSetTorus<float>(20.0f, 6.0f, nanovdb::Vec3f(0), 1.0, 3.0,
                                               nanovdb::Vec3d(0), name);
}

/// Float grid with tiles at every level (root tile, upper tile, lower tile)
/// whose values are the extremes: value_max = 100 (root tile), value_min = -50
/// (an inactive upper-node tile). Built with OpenVDB, converted by NanoVDB.
Handle tile_grid() {
    openvdb::initialize();
    auto g = openvdb::FloatGrid::create(0.5f);
    g->setName("tiles");
    g->setGridClass(openvdb::GRID_FOG_VOLUME);
    g->setTransform(openvdb::math::Transform::createLinearTransform(0.25));
    auto &tree = g->tree();
    tree.addTile(3, openvdb::Coord(-4096, 0, 0), 100.0f, true);  // root tile
    tree.addTile(2, openvdb::Coord(0, 0, 128), -50.0f, false);    // upper-node tile
    tree.addTile(1, openvdb::Coord(8, 0, 0), 7.0f, true);         // lower-node tile
    tree.setValue(openvdb::Coord(1, 2, 3), 3.0f);
    tree.setValue(openvdb::Coord(-1, -1, -1), -2.0f);
    tree.setValue(openvdb::Coord(5000, -300, 20), 9.0f);
    return nanovdb::openToNanoVDB(*g);
}

/// Float grid with NaN and +-Inf voxels, statistics disabled.
Handle nan_inf_grid() {
    nanovdb::GridBuilder<float> builder(0.0f, nanovdb::GridClass::FogVolume);
    builder.setStats(nanovdb::StatsMode::Disable);
    auto acc = builder.getAccessor();
    const float nan = std::numeric_limits<float>::quiet_NaN();
    const float inf = std::numeric_limits<float>::infinity();
    acc.setValue(nanovdb::Coord(0, 0, 0), nan);
    acc.setValue(nanovdb::Coord(1, 0, 0), nan);
    acc.setValue(nanovdb::Coord(2, 0, 0), inf);
    acc.setValue(nanovdb::Coord(300, 0, 0), -inf);
    acc.setValue(nanovdb::Coord(3, 0, 0), 4.0f);
    return builder.getHandle(1.0, nanovdb::Vec3d(0), "nan_inf");
}

Handle empty_grid() {
    nanovdb::GridBuilder<float> builder(1.5f, nanovdb::GridClass::FogVolume);
    return builder.getHandle(1.0, nanovdb::Vec3d(0), "empty");
}

template <typename T> Handle typed_grid(const std::string &name, T value) {
    nanovdb::GridBuilder<T> builder(T{}, nanovdb::GridClass::Unknown);
    auto acc = builder.getAccessor();
    acc.setValue(nanovdb::Coord(1, 2, 3), value);
    acc.setValue(nanovdb::Coord(-40, 7, 100), value);
    return builder.getHandle(1.0, nanovdb::Vec3d(0), name);
}

/// All values a PNanoVDB lookup can return, through NanoVDB's own node structs.
struct Brute {
    float vmin = std::numeric_limits<float>::infinity();
    float vmax = -std::numeric_limits<float>::infinity();
    uint64_t nan = 0, inf = 0, seen = 0;
    void add(float v) {
        if (std::isnan(v)) { ++nan; return; }
        if (std::isinf(v)) ++inf;
        ++seen;
        vmin = std::min(vmin, v);
        vmax = std::max(vmax, v);
    }
};

Brute brute_force(const nanovdb::FloatGrid &grid) {
    Brute b;
    const auto &tree = grid.tree();
    const auto &root = tree.root();
    b.add(root.background());
    for (uint32_t i = 0; i < root.tileCount(); ++i) {
        const auto *tile = root.data()->tile(i);
        if (!tile->isChild()) b.add(tile->value);
    }
    const auto *upper = tree.getFirstNode<2>();
    for (uint32_t i = 0; i < tree.nodeCount(2); ++i)
        for (uint32_t n = 0; n < 32768; ++n)
            if (!upper[i].data()->isChild(n)) b.add(upper[i].data()->getValue(n));
    const auto *lower = tree.getFirstNode<1>();
    for (uint32_t i = 0; i < tree.nodeCount(1); ++i)
        for (uint32_t n = 0; n < 4096; ++n)
            if (!lower[i].data()->isChild(n)) b.add(lower[i].data()->getValue(n));
    const auto *leaf = tree.getFirstNode<0>();
    for (uint32_t i = 0; i < tree.nodeCount(0); ++i)
        for (uint32_t n = 0; n < 512; ++n) b.add(leaf[i].getValue(n));
    return b;
}

/// validate_float_grid's summary against the NanoVDB C++ API.
void check_info_against_nanovdb(const nio::FloatGridInfo &info, const nanovdb::FloatGrid &grid) {
    const auto &tree = grid.tree();
    const auto &root = tree.root();
    const auto bbox = root.bbox();
    for (int i = 0; i < 3; ++i) {
        CHECK(info.bbox_min[i] == bbox.min()[i]);
        CHECK(info.bbox_max[i] == bbox.max()[i]);
        CHECK(info.voxel_size[i] == grid.voxelSize()[i]);
        CHECK(info.map_vec[i] == grid.map().mVecD[i]);
    }
    for (int i = 0; i < 9; ++i) {
        CHECK(info.map_mat[i] == grid.map().mMatD[i]);
        CHECK(info.map_inv[i] == grid.map().mInvMatD[i]);
    }
    CHECK(info.empty == bbox.empty());
    CHECK(info.background == root.background());
    CHECK(uint64_t(info.root_word) * 4 ==
          uint64_t(reinterpret_cast<const uint8_t *>(&root) -
                   reinterpret_cast<const uint8_t *>(&grid)));
    CHECK(info.node_count[0] == tree.nodeCount(0));
    CHECK(info.node_count[1] == tree.nodeCount(1));
    CHECK(info.node_count[2] == tree.nodeCount(2));
    CHECK(info.active_voxel_count == grid.activeVoxelCount());
    CHECK(info.grid_class == uint32_t(grid.gridClass()));
    CHECK(info.name == std::string(grid.gridName()));

    const Brute b = brute_force(grid);
    CHECK(info.nan_count == b.nan);
    CHECK(info.inf_count == b.inf);
    if (b.seen > 0) {
        CHECK(info.value_min == b.vmin);
        CHECK(info.value_max == b.vmax);
    } else {
        CHECK(std::isnan(info.value_min));
        CHECK(std::isnan(info.value_max));
    }
}

nio::FloatGridInfo validate_handle(const Handle &h, const std::string &label) {
    return nio::validate_float_grid(label, h.data(), h.size());
}

// Offsets (in the grid buffer) of NanoVDB structures, found with its API.
template <typename T> uint64_t offset_in(const nanovdb::FloatGrid &grid, const T *p) {
    return uint64_t(reinterpret_cast<const uint8_t *>(p) -
                    reinterpret_cast<const uint8_t *>(&grid));
}

} // namespace

// =====================================================================================
TEST_CASE("grid_type_name and describe_grids") {
    CHECK(nio::grid_type_name(1) == "float");
    CHECK(nio::grid_type_name(2) == "double");
    CHECK(nio::grid_type_name(4) == "int32");
    CHECK(nio::grid_type_name(6) == "Vec3f");
    CHECK(nio::grid_type_name(9) == "Half");
    CHECK(nio::grid_type_name(16) == "FpN");
    CHECK(nio::grid_type_name(19) == "Index");
    CHECK(nio::grid_type_name(20) == "OnIndex");
    CHECK(nio::grid_type_name(22) == "OnIndexMask");
    CHECK(nio::grid_type_name(26) == "UInt8");
    CHECK(nio::grid_type_name(0) == "unknown (0)");
    CHECK(nio::grid_type_name(27) == "unknown (27)");
    CHECK(nio::grid_type_name(0xffffffffu) == "unknown (4294967295)");
    // The 32.4 table agrees with our names where both exist (apart from
    // NanoVDB's spelling of the Fp types, "Float4"...).
    for (uint32_t t = 1; t < uint32_t(nanovdb::GridType::End); ++t) {
        if (t >= 13 && t <= 16) continue;
        CHECK(nio::grid_type_name(t) == nanovdb::toStr(nanovdb::GridType(t)));
    }

    std::vector<nio::GridEntry> grids(2);
    grids[0].name = "density";
    grids[0].grid_type = 1;
    grids[1].name = "temperature";
    grids[1].grid_type = 1;
    CHECK(nio::describe_grids(grids) == "0: \"density\" (float), 1: \"temperature\" (float)");
    grids[1].grid_type = 6;
    grids[1].name = "";
    CHECK(nio::describe_grids(grids) == "0: \"density\" (float), 1: \"\" (Vec3f)");
}

// =====================================================================================
TEST_CASE("validate_float_grid on NanoVDB-made float grids") {
    const Handle sphere = fog_sphere(), torus = ls_torus(), tiles = tile_grid(),
                 nans = nan_inf_grid(), empty = empty_grid();

    SUBCASE("fog sphere") {
        const auto *grid = sphere.grid<float>();
        REQUIRE(grid);
        const auto info = validate_handle(sphere, "sphere");
        check_info_against_nanovdb(info, *grid);
        CHECK(info.name == "density");
        CHECK(info.grid_class == uint32_t(nanovdb::GridClass::FogVolume));
        CHECK(!info.empty);
        // NanoVDB 32.4's createFogVolumeSphere keeps the level set's
        // background (half width 3 x voxel size 0.5) in the root: a lookup
        // far outside returns 1.5, above every voxel value (0..1). This is
        // why value_max must include the background.
        CHECK(info.background == 1.5f);
        CHECK(info.value_min == 0.0f);
        CHECK(info.value_max == 1.5f);
        CHECK(info.voxel_size[0] == 0.5);
        CHECK(info.map_vec[0] == 0.25);
    }
    SUBCASE("level-set torus") {
        const auto info = validate_handle(torus, "torus");
        check_info_against_nanovdb(info, *torus.grid<float>());
        CHECK(info.background == 3.0f); // half width 3 x voxel size 1
        CHECK(info.value_max == 3.0f);
        CHECK(info.value_min == -3.0f);
    }
    SUBCASE("tiles at every level (OpenVDB)") {
        const auto *grid = tiles.grid<float>();
        REQUIRE(grid);
        const auto info = validate_handle(tiles, "tiles");
        check_info_against_nanovdb(info, *grid);
        CHECK(info.value_max == 100.0f); // the root tile
        CHECK(info.value_min == -50.0f); // the inactive upper tile
        CHECK(info.background == 0.5f);
        CHECK(info.bbox_min[0] == -4096);
        CHECK(info.voxel_size[1] == 0.25);
        // The grid really has a tile at each level.
        const auto &root = grid->tree().root();
        bool root_tile = false;
        for (uint32_t i = 0; i < root.tileCount(); ++i)
            root_tile |= !root.data()->tile(i)->isChild();
        CHECK(root_tile);
    }
    SUBCASE("NaN and Inf values, no statistics") {
        const auto info = validate_handle(nans, "nans");
        check_info_against_nanovdb(info, *nans.grid<float>());
        CHECK(info.nan_count == 2);
        CHECK(info.inf_count == 2);
        CHECK(info.value_min == -std::numeric_limits<float>::infinity());
        CHECK(info.value_max == std::numeric_limits<float>::infinity());
    }
    SUBCASE("empty grid") {
        const auto info = validate_handle(empty, "empty");
        check_info_against_nanovdb(info, *empty.grid<float>());
        CHECK(info.empty);
        CHECK(info.node_count[0] == 0);
        CHECK(info.node_count[2] == 0);
        CHECK(info.value_min == 1.5f);
        CHECK(info.value_max == 1.5f);
    }
    SUBCASE("buffer larger than the grid: only the first grid is used") {
        Bytes b = handle_bytes(sphere);
        const Bytes t = handle_bytes(torus);
        b.insert(b.end(), t.begin(), t.end());
        const auto info = nio::validate_float_grid("two", b.data(), b.size());
        check_info_against_nanovdb(info, *sphere.grid<float>());
    }
}

// =====================================================================================
TEST_CASE("validate_float_grid rejects hostile buffers") {
    const Handle sphere = fog_sphere();
    const Handle tiles = tile_grid();
    const auto &grid = *sphere.grid<float>();
    const auto &tree = grid.tree();
    const auto &root = tree.root();
    const Bytes good = handle_bytes(sphere);
    const std::string p = "hostile.nvdb";
    REQUIRE(tree.nodeCount(0) > 0);
    REQUIRE(tree.nodeCount(1) > 0);
    REQUIRE(tree.nodeCount(2) > 0);
    const uint64_t tree_off = offset_in(grid, &tree);
    const uint64_t root_off = offset_in(grid, &root);
    const uint64_t upper0 = offset_in(grid, tree.getFirstNode<2>());
    const uint64_t lower0 = offset_in(grid, tree.getFirstNode<1>());
    const uint64_t leaf0 = offset_in(grid, tree.getFirstNode<0>());
    CHECK(tree_off == 672);

    auto validate = [&](const Bytes &b) { return nio::validate_float_grid(p, b.data(), b.size()); };
    CHECK_NOTHROW(validate(good));

    SUBCASE("too small") {
        Bytes b(good.begin(), good.begin() + 700);
        CHECK_IO_ERROR(validate(b), p, "700 bytes", "too small");
        CHECK_IO_ERROR(nio::validate_float_grid(p, nullptr, 0), p, "too small");
    }
    SUBCASE("16 GiB or more") {
        // Rejected from the size alone, before any byte is read.
        CHECK_IO_ERROR(nio::validate_float_grid(p, good.data(), uint64_t(1) << 34), p, "16 GiB");
    }
    SUBCASE("wrong magic") {
        Bytes b = good;
        std::memcpy(b.data(), "NotAGrid", 8);
        CHECK_IO_ERROR(validate(b), p, "not a NanoVDB grid", "NotAGrid");
        std::memcpy(b.data(), "NanoVDB2", 8); // a file magic, not a grid magic
        CHECK_IO_ERROR(validate(b), p, "NanoVDB2");
    }
    SUBCASE("byte-swapped magic") {
        Bytes b = good;
        std::reverse(b.begin(), b.begin() + 8);
        CHECK_IO_ERROR(validate(b), p, "byte-swapped");
    }
    SUBCASE("version 31 and 33") {
        Bytes b = good;
        poke<uint32_t>(b, 16, packed_version(31, 0, 0));
        CHECK_IO_ERROR(validate(b), p, "31.0.0", "major version 32");
        poke<uint32_t>(b, 16, packed_version(33, 1, 2));
        CHECK_IO_ERROR(validate(b), p, "33.1.2");
    }
    SUBCASE("not a float grid") {
        Bytes b = good;
        poke<uint32_t>(b, 636, 2);
        CHECK_IO_ERROR(validate(b), p, "double", "only float grids");
        poke<uint32_t>(b, 636, 20);
        CHECK_IO_ERROR(validate(b), p, "OnIndex", "only float grids");
    }
    SUBCASE("mGridSize larger than the buffer") {
        Bytes b = good;
        poke<uint64_t>(b, 32, good.size() + 32);
        CHECK_IO_ERROR(validate(b), p, "mGridSize", std::to_string(good.size() + 32));
        poke<uint64_t>(b, 32, 100);
        CHECK_IO_ERROR(validate(b), p, "mGridSize", "smaller");
    }
    SUBCASE("root offset outside the buffer") {
        Bytes b = good;
        poke<uint64_t>(b, tree_off + 24, good.size());
        CHECK_IO_ERROR(validate(b), p, "root node offset", "outside");
        poke<uint64_t>(b, tree_off + 24, ~uint64_t(0));
        CHECK_IO_ERROR(validate(b), p, "root node offset", "outside");
    }
    SUBCASE("misaligned root and node arrays") {
        Bytes b = good;
        poke<uint64_t>(b, tree_off + 24, root_off - tree_off + 8);
        CHECK_IO_ERROR(validate(b), p, "root node", "not 32-byte aligned");
        b = good;
        poke<uint64_t>(b, tree_off + 8, lower0 - tree_off + 4);
        CHECK_IO_ERROR(validate(b), p, "lower node array", "not 32-byte aligned");
    }
    SUBCASE("root table_size absurd") {
        Bytes b = good;
        poke<uint32_t>(b, root_off + 24, 0xffffffffu);
        CHECK_IO_ERROR(validate(b), p, "root tile table", "4294967295");
    }
    SUBCASE("node arrays that do not fit") {
        Bytes b = good;
        poke<uint32_t>(b, tree_off + 32, 0x7fffffffu); // leaf count
        CHECK_IO_ERROR(validate(b), p, "leaf node array", "does not fit");
        b = good;
        poke<uint64_t>(b, tree_off + 16, ~uint64_t(0) - 5); // upper offset
        CHECK_IO_ERROR(validate(b), p, "upper node array", "does not fit");
    }
    // A root tile with a child.
    uint32_t child_tile = 0;
    while (child_tile < root.tileCount() && !root.data()->tile(child_tile)->isChild()) ++child_tile;
    REQUIRE(child_tile < root.tileCount());
    const uint64_t tile_child = offset_in(grid, root.data()->tile(child_tile)) + 8;
    CHECK(tile_child == root_off + 64 + 32 * child_tile + 8);

    SUBCASE("root tile child outside the buffer") {
        Bytes b = good;
        poke<int64_t>(b, tile_child, int64_t(1) << 40);
        CHECK_IO_ERROR(validate(b), p, "root tile", "outside");
        poke<int64_t>(b, tile_child, std::numeric_limits<int64_t>::min());
        CHECK_IO_ERROR(validate(b), p, "root tile", "outside");
        poke<int64_t>(b, tile_child, -int64_t(root_off) - 8);
        CHECK_IO_ERROR(validate(b), p, "root tile", "outside");
    }
    SUBCASE("root tile child misaligned or outside the upper array") {
        Bytes b = good;
        poke<int64_t>(b, tile_child, peek<int64_t>(good, tile_child) + 32);
        CHECK_IO_ERROR(validate(b), p, "root tile", "misaligned", "upper");
        poke<int64_t>(b, tile_child, int64_t(leaf0) - int64_t(root_off));
        CHECK_IO_ERROR(validate(b), p, "root tile", "outside the upper node array");
    }
    SUBCASE("upper child pointing outside the lower array") {
        const auto *upper = tree.getFirstNode<2>();
        uint32_t n = 0;
        while (n < 32768 && !upper->childMask().isOn(n)) ++n;
        REQUIRE(n < 32768);
        const uint64_t entry = offset_in(grid, &upper->data()->mTable[n]);
        CHECK(entry == upper0 + 8256 + 8 * n);
        Bytes b = good;
        poke<int64_t>(b, entry, int64_t(leaf0) - int64_t(upper0)); // at the leaf array
        CHECK_IO_ERROR(validate(b), p, "upper node 0", "table entry " + std::to_string(n),
                       "outside the lower node array");
        poke<int64_t>(b, entry, int64_t(good.size()));
        CHECK_IO_ERROR(validate(b), p, "upper node 0", "outside");
        poke<int64_t>(b, entry, peek<int64_t>(good, entry) + 4);
        CHECK_IO_ERROR(validate(b), p, "upper node 0", "misaligned");
    }
    SUBCASE("lower child pointing outside the leaf array") {
        const auto *lower = tree.getFirstNode<1>();
        uint32_t n = 0;
        while (n < 4096 && !lower->childMask().isOn(n)) ++n;
        REQUIRE(n < 4096);
        const uint64_t entry = offset_in(grid, &lower->data()->mTable[n]);
        CHECK(entry == lower0 + 1088 + 8 * n);
        Bytes b = good;
        poke<int64_t>(b, entry, 0); // the lower node itself
        CHECK_IO_ERROR(validate(b), p, "lower node 0", "outside the leaf node array");
        poke<int64_t>(b, entry, -int64_t(lower0) - 1);
        CHECK_IO_ERROR(validate(b), p, "lower node 0", "outside");
    }
    SUBCASE("a child bit set in a grid with no nodes below") {
        Bytes b = good;
        poke<uint32_t>(b, tree_off + 32, 0); // pretend there are no leaves
        CHECK_IO_ERROR(validate(b), p, "lower node", "no leaf nodes");
    }
    SUBCASE("tile grid: a root tile value made a child") {
        const auto &tg = *tiles.grid<float>();
        const auto &troot = tg.tree().root();
        uint32_t value_tile = 0;
        while (value_tile < troot.tileCount() && troot.data()->tile(value_tile)->isChild())
            ++value_tile;
        REQUIRE(value_tile < troot.tileCount());
        Bytes b = handle_bytes(tiles);
        poke<int64_t>(b, offset_in(tg, troot.data()->tile(value_tile)) + 8, 64);
        CHECK_IO_ERROR(nio::validate_float_grid(p, b.data(), b.size()), p,
                       ("root tile " + std::to_string(value_tile)), "upper");
    }
}

// =====================================================================================
TEST_CASE("files written by NanoVDB 32.4: list_grids, select_grid, read_grid") {
    const Handle sphere = fog_sphere("density"), torus = ls_torus("surface"),
                 nans = nan_inf_grid();
    const uint32_t version32_4 = nanovdb::Version().id();

    for (const auto codec : { nanovdb::io::Codec::NONE, nanovdb::io::Codec::ZIP,
                              nanovdb::io::Codec::BLOSC }) {
        const std::string cname = nanovdb::io::toStr(codec);
        SUBCASE(("one grid, " + cname).c_str()) {
            const std::string path = tmp_path("one_" + cname + ".nvdb");
            nanovdb::io::writeGrid(path, sphere, codec);
            const auto grids = nio::list_grids(path);
            REQUIRE(grids.size() == 1);
            const auto &e = grids[0];
            CHECK(e.name == "density");
            CHECK(e.grid_type == 1);
            CHECK(e.grid_class == uint32_t(nanovdb::GridClass::FogVolume));
            CHECK(e.grid_size == sphere.size());
            CHECK(e.codec == nio::Codec(uint16_t(codec)));
            CHECK(e.version == version32_4);
            CHECK(e.segment == 0);
            CHECK(!e.raw);
            CHECK(e.file_offset == 16 + 176 + std::string("density").size() + 1);
            CHECK(e.file_offset + e.file_size == fs::file_size(path));
            if (codec == nanovdb::io::Codec::NONE) CHECK(e.file_size == e.grid_size);
            else CHECK(e.file_size < e.grid_size);

            const Aligned buf = load(path, e);
            CHECK(buf.bytes() == handle_bytes(sphere));
            const Handle ref = nanovdb::io::readGrid(path, 0);
            CHECK(buf.bytes() == handle_bytes(ref));
            const auto info = nio::validate_float_grid(path, buf.data(), buf.size);
            check_info_against_nanovdb(info, *ref.grid<float>());
            CHECK(&nio::select_grid(path, grids, "") == &grids[0]);
        }
        SUBCASE(("three grids in one segment, " + cname).c_str()) {
            const std::string path = tmp_path("three_" + cname + ".nvdb");
            std::vector<Handle> handles;
            handles.push_back(fog_sphere("density"));
            handles.push_back(ls_torus("surface"));
            handles.push_back(nan_inf_grid());
            nanovdb::io::writeGrids(path, handles, codec);
            const auto grids = nio::list_grids(path);
            REQUIRE(grids.size() == 3);
            CHECK(nio::describe_grids(grids) ==
                  "0: \"density\" (float), 1: \"surface\" (float), 2: \"nan_inf\" (float)");
            uint64_t expect_offset = 16;
            for (const auto &g : grids) expect_offset += 176 + g.name.size() + 1;
            for (size_t i = 0; i < grids.size(); ++i) {
                INFO("grid " << i);
                CHECK(grids[i].segment == 0);
                CHECK(grids[i].file_offset == expect_offset);
                expect_offset += grids[i].file_size;
                CHECK(grids[i].grid_size == handles[i].size());
                const Aligned buf = load(path, grids[i]);
                CHECK(buf.bytes() == handle_bytes(handles[i]));
                CHECK(buf.bytes() == handle_bytes(nanovdb::io::readGrid(path, i)));
                CHECK_NOTHROW(nio::validate_float_grid(path, buf.data(), buf.size));
            }
            CHECK(expect_offset == fs::file_size(path));
            CHECK(&nio::select_grid(path, grids, "surface") == &grids[1]);
            CHECK(&nio::select_grid(path, grids, "nan_inf") == &grids[2]);
            CHECK(&nio::select_grid(path, grids, "2") == &grids[2]);
            CHECK(&nio::select_grid(path, grids, "") == &grids[0]);
            CHECK_IO_ERROR(nio::select_grid(path, grids, "3"), path, "\"3\" not found",
                           "0: \"density\" (float), 1: \"surface\" (float), 2: \"nan_inf\" (float)");
            CHECK_IO_ERROR(nio::select_grid(path, grids, "temperature"), path,
                           "\"temperature\" not found", "1: \"surface\" (float)");
            CHECK_IO_ERROR(nio::select_grid(path, grids, "-1"), path, "not found");
        }
    }
    SUBCASE("two segments (two files concatenated), different codecs") {
        const std::string a = tmp_path("seg_a.nvdb"), b = tmp_path("seg_b.nvdb"),
                          path = tmp_path("two_segments.nvdb");
        std::vector<Handle> first;
        first.push_back(fog_sphere("density"));
        first.push_back(ls_torus("surface"));
        nanovdb::io::writeGrids(a, first, nanovdb::io::Codec::ZIP);
        nanovdb::io::writeGrid(b, nans, nanovdb::io::Codec::BLOSC);
        Bytes all = read_bytes(a);
        const Bytes tail = read_bytes(b);
        all.insert(all.end(), tail.begin(), tail.end());
        write_bytes(path, all);

        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 3);
        CHECK(grids[0].segment == 0);
        CHECK(grids[1].segment == 0);
        CHECK(grids[2].segment == 1);
        CHECK(grids[0].codec == nio::Codec::Zip);
        CHECK(grids[2].codec == nio::Codec::Blosc);
        CHECK(grids[2].file_offset == read_bytes(a).size() + 16 + 176 + 8);
        for (size_t i = 0; i < 3; ++i) {
            INFO("grid " << i);
            const Aligned buf = load(path, grids[i]);
            CHECK(buf.bytes() == handle_bytes(nanovdb::io::readGrid(path, i)));
        }
        CHECK(load(path, grids[2]).bytes() == handle_bytes(nans));
        CHECK(&nio::select_grid(path, grids, "nan_inf") == &grids[2]);
    }
    SUBCASE("mixed value types: only float grids are selectable") {
        const std::string path = tmp_path("mixed.nvdb");
        std::vector<Handle> handles;
        handles.push_back(typed_grid<double>("dbl", 2.5));
        handles.push_back(typed_grid<int32_t>("ints", 7));
        handles.push_back(typed_grid<nanovdb::Vec3f>("vel", nanovdb::Vec3f(1, 2, 3)));
        handles.push_back(fog_sphere("density"));
        nanovdb::io::writeGrids(path, handles, nanovdb::io::Codec::ZIP);
        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 4);
        CHECK(grids[0].grid_type == 2);
        CHECK(grids[1].grid_type == 4);
        CHECK(grids[2].grid_type == 6);
        CHECK(grids[3].grid_type == 1);
        CHECK(&nio::select_grid(path, grids, "") == &grids[3]);
        CHECK(&nio::select_grid(path, grids, "density") == &grids[3]);
        CHECK_IO_ERROR(nio::select_grid(path, grids, "dbl"), path, "\"dbl\"", "type double",
                       "only float grids are supported", "supported types: float");
        CHECK_IO_ERROR(nio::select_grid(path, grids, "ints"), path, "type int32", "only float");
        CHECK_IO_ERROR(nio::select_grid(path, grids, "2"), path, "type Vec3f", "only float");
        // Non-float payloads still decode byte-exactly.
        for (size_t i = 0; i < 3; ++i)
            CHECK(load(path, grids[i]).bytes() == handle_bytes(handles[i]));

        const std::string nofloat = tmp_path("nofloat.nvdb");
        handles.pop_back();
        nanovdb::io::writeGrids(nofloat, handles, nanovdb::io::Codec::NONE);
        const auto g2 = nio::list_grids(nofloat);
        CHECK_IO_ERROR(nio::select_grid(nofloat, g2, ""), nofloat, "no float grid",
                       "0: \"dbl\" (double), 1: \"ints\" (int32), 2: \"vel\" (Vec3f)");
    }
    SUBCASE("names take priority over indices; unnamed grids") {
        const std::string path = tmp_path("names.nvdb");
        std::vector<Handle> handles;
        handles.push_back(fog_sphere("a"));
        handles.push_back(fog_sphere("0"));
        handles.push_back(fog_sphere(""));
        nanovdb::io::writeGrids(path, handles, nanovdb::io::Codec::NONE);
        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 3);
        CHECK(grids[2].name.empty());
        CHECK(&nio::select_grid(path, grids, "0") == &grids[1]); // the name "0"
        CHECK(&nio::select_grid(path, grids, "2") == &grids[2]); // index 2
        CHECK(&nio::select_grid(path, grids, "a") == &grids[0]);
        CHECK(&nio::select_grid(path, grids, "") == &grids[0]);
        CHECK_IO_ERROR(nio::select_grid(path, grids, "99999999999999999999999"), path,
                       "not found", "2: \"\" (float)");
    }
}

// =====================================================================================
TEST_CASE("newer file forms: NanoVDB2 header, NanoVDB1 grids, raw grid buffers") {
    const Handle sphere = fog_sphere("density"), torus = ls_torus("surface");
    const Bytes sphere_bytes = handle_bytes(sphere), torus_bytes = handle_bytes(torus);
    const auto ref_info = validate_handle(sphere, "ref");

    SUBCASE("32.8+: NanoVDB2 file header, NanoVDB1 grid magic, version 32.8.0") {
        const std::string base = tmp_path("v2_base.nvdb"), path = tmp_path("v2.nvdb");
        nanovdb::io::writeGrid(base, sphere, nanovdb::io::Codec::NONE);
        Bytes b = read_bytes(base);
        const auto grids0 = nio::list_grids(base);
        std::memcpy(b.data(), "NanoVDB2", 8);
        poke<uint32_t>(b, 8, packed_version(32, 8, 0));
        std::memcpy(b.data() + grids0[0].file_offset, "NanoVDB1", 8);
        write_bytes(path, b);

        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 1);
        CHECK(grids[0].version == packed_version(32, 8, 0));
        CHECK(grids[0].name == "density");
        CHECK(!grids[0].raw);
        const Aligned buf = load(path, grids[0]);
        Bytes expect = sphere_bytes;
        std::memcpy(expect.data(), "NanoVDB1", 8);
        CHECK(buf.bytes() == expect);
        const auto info = nio::validate_float_grid(path, buf.data(), buf.size);
        CHECK(info.value_max == ref_info.value_max);
        CHECK(info.active_voxel_count == ref_info.active_voxel_count);
        check_info_against_nanovdb(info, *sphere.grid<float>());
    }
    SUBCASE("raw grid buffer, NanoVDB0 grid magic (32.6/32.7)") {
        const std::string path = tmp_path("raw0.nvdb");
        write_bytes(path, sphere_bytes);
        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 1);
        const auto &e = grids[0];
        CHECK(e.raw);
        CHECK(e.name == "density");
        CHECK(e.grid_type == 1);
        CHECK(e.grid_class == uint32_t(nanovdb::GridClass::FogVolume));
        CHECK(e.grid_size == sphere.size());
        CHECK(e.file_offset == 0);
        CHECK(e.file_size == sphere.size());
        CHECK(e.codec == nio::Codec::None);
        CHECK(e.version == sphere.grid<float>()->version().id());
        const Aligned buf = load(path, e);
        CHECK(buf.bytes() == sphere_bytes);
        check_info_against_nanovdb(nio::validate_float_grid(path, buf.data(), buf.size),
                                   *sphere.grid<float>());
    }
    SUBCASE("raw grid buffer, NanoVDB1 grid magic, two grids back to back") {
        const std::string path = tmp_path("raw1.nvdb");
        Bytes b = sphere_bytes;
        b.insert(b.end(), torus_bytes.begin(), torus_bytes.end());
        std::memcpy(b.data(), "NanoVDB1", 8);
        std::memcpy(b.data() + sphere_bytes.size(), "NanoVDB1", 8);
        write_bytes(path, b);
        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 2);
        CHECK(nio::describe_grids(grids) == "0: \"density\" (float), 1: \"surface\" (float)");
        CHECK(grids[1].file_offset == sphere_bytes.size());
        CHECK(grids[1].raw);
        const Aligned buf = load(path, nio::select_grid(path, grids, "surface"));
        Bytes expect = torus_bytes;
        std::memcpy(expect.data(), "NanoVDB1", 8);
        CHECK(buf.bytes() == expect);
        check_info_against_nanovdb(nio::validate_float_grid(path, buf.data(), buf.size),
                                   *torus.grid<float>());
    }
    SUBCASE("raw grid whose checksum looks like a segment header") {
        // Bytes 8..15 of a grid are its checksum; make them read as a 32.x
        // segment header (version, 1 grid, codec NONE). The segment reading
        // fails, and the loader falls back to the raw reading.
        const std::string path = tmp_path("raw_ambiguous.nvdb");
        Bytes b = sphere_bytes;
        poke<uint32_t>(b, 8, packed_version(32, 4, 2));
        poke<uint16_t>(b, 12, 1);
        poke<uint16_t>(b, 14, 0);
        write_bytes(path, b);
        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 1);
        CHECK(grids[0].raw);
        CHECK(load(path, grids[0]).bytes() == b);
    }
    SUBCASE("raw grid buffer truncated") {
        const std::string path = tmp_path("raw_truncated.nvdb");
        write_bytes(path, Bytes(sphere_bytes.begin(), sphere_bytes.end() - 100));
        CHECK_IO_ERROR(nio::list_grids(path), path, "beyond the end of the file");
        Bytes two = sphere_bytes;
        two.insert(two.end(), torus_bytes.begin(), torus_bytes.begin() + 300);
        write_bytes(path, two);
        CHECK_IO_ERROR(nio::list_grids(path), path, "grid 1", "truncated grid header");
    }
}

// =====================================================================================
TEST_CASE("list_grids and read_grid reject hostile files") {
    const Handle sphere = fog_sphere("density"), torus = ls_torus("surface");
    std::vector<Handle> two;
    two.push_back(fog_sphere("density"));
    two.push_back(ls_torus("surface"));
    const std::string none_path = tmp_path("h_none.nvdb"), zip_path = tmp_path("h_zip.nvdb"),
                      blosc_path = tmp_path("h_blosc.nvdb"), two_path = tmp_path("h_two.nvdb");
    nanovdb::io::writeGrid(none_path, sphere, nanovdb::io::Codec::NONE);
    nanovdb::io::writeGrid(zip_path, sphere, nanovdb::io::Codec::ZIP);
    nanovdb::io::writeGrid(blosc_path, sphere, nanovdb::io::Codec::BLOSC);
    nanovdb::io::writeGrids(two_path, two, nanovdb::io::Codec::ZIP);
    const Bytes none = read_bytes(none_path), zip = read_bytes(zip_path),
                blosc = read_bytes(blosc_path), twob = read_bytes(two_path);
    const uint64_t payload = 16 + 176 + 8; // header + metadata + "density\0"
    const std::string p = tmp_path("hostile.nvdb");
    auto write = [&](const Bytes &b) { write_bytes(p, b); };

    SUBCASE("missing file, directory") {
        const std::string missing = tmp_path("does_not_exist.nvdb");
        CHECK_IO_ERROR(nio::list_grids(missing), missing, "not found");
        const std::string dir = fs::path(p).parent_path().string();
        CHECK_IO_ERROR(nio::list_grids(dir), dir, "directory");
        nio::GridEntry e = nio::list_grids(none_path)[0];
        CHECK_IO_ERROR(nio::read_grid(missing, e, nullptr), missing, "not found");
    }
    SUBCASE("empty file") {
        write({});
        CHECK_IO_ERROR(nio::list_grids(p), p, "empty");
    }
    SUBCASE("random bytes") {
        std::mt19937 rng(1234);
        Bytes b(4096);
        for (auto &c : b) c = uint8_t(rng());
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "not a NanoVDB file", "first 8 bytes");
        write(Bytes(b.begin(), b.begin() + 5));
        CHECK_IO_ERROR(nio::list_grids(p), p, "not a NanoVDB file", "5 bytes");
    }
    SUBCASE("wrong magic; an OpenVDB file") {
        Bytes b = none;
        std::memcpy(b.data(), "NanoVDBX", 8);
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "not a NanoVDB file", "NanoVDBX");
        const std::string vdb = shared_data_dir() + "/openvdb_sphere_ls.vdb";
        if (fs::exists(vdb))
            CHECK_IO_ERROR(nio::list_grids(vdb), vdb, "not a NanoVDB file", "OpenVDB");
    }
    SUBCASE("byte-swapped magic") {
        Bytes b = none;
        std::reverse(b.begin(), b.begin() + 8);
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "byte-swapped", "big-endian");
    }
    SUBCASE("major version 31 and 33") {
        Bytes b = none;
        poke<uint32_t>(b, 8, packed_version(31, 4, 2));
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "version 31.4.2", "only major version 32");
        poke<uint32_t>(b, 8, packed_version(33, 0, 1));
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "version 33.0.1", "only major version 32");
    }
    SUBCASE("truncated header") {
        write(Bytes(none.begin(), none.begin() + 12));
        CHECK_IO_ERROR(nio::list_grids(p), p, "truncated segment header");
    }
    SUBCASE("truncated metadata") {
        write(Bytes(none.begin(), none.begin() + 16 + 100));
        CHECK_IO_ERROR(nio::list_grids(p), p, "truncated metadata");
        // Grid count larger than the metadata that follows.
        Bytes b = none;
        poke<uint16_t>(b, 12, 60000);
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "truncated metadata", "60000 grids");
    }
    SUBCASE("truncated name") {
        write(Bytes(none.begin(), none.begin() + 16 + 176 + 3));
        CHECK_IO_ERROR(nio::list_grids(p), p, "truncated name");
        Bytes b = none;
        poke<uint32_t>(b, 16 + 136, 0xfffffff0u); // absurd name size
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "truncated name", "4294967280");
    }
    SUBCASE("truncated payload") {
        write(Bytes(zip.begin(), zip.end() - 10));
        CHECK_IO_ERROR(nio::list_grids(p), p, "\"density\"", "beyond the end of the file");
        // The file shrinks after list_grids: read_grid notices.
        write(zip);
        const auto grids = nio::list_grids(p);
        write(Bytes(zip.begin(), zip.end() - 10));
        CHECK_IO_ERROR(nio::read_grid(p, grids[0], Aligned(grids[0].grid_size).data()), p,
                       "truncated payload");
    }
    SUBCASE("payload offset beyond EOF") {
        const auto grids = nio::list_grids(two_path);
        REQUIRE(grids.size() == 2);
        // Cut right after the first payload: the second starts at EOF.
        write(Bytes(twob.begin(), twob.begin() + grids[1].file_offset));
        CHECK_IO_ERROR(nio::list_grids(p), p, "grid 1 \"surface\"", "beyond the end of the file");
        // A first grid whose payload size runs past the end of the file.
        Bytes b = twob;
        poke<uint64_t>(b, 16 + 8, uint64_t(1) << 62);
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "grid 0 \"density\"", "beyond the end of the file");
    }
    SUBCASE("absurd grid_size: rejected before any allocation") {
        Bytes b = none;
        poke<uint64_t>(b, 16, uint64_t(1) << 60);
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "1152921504606846976", "16 GiB");
        b = zip;
        poke<uint64_t>(b, 16, uint64_t(1) << 33); // 8 GiB from a few KiB of zlib
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "8589934592", "implausible", "1100:1");
        b = none;
        poke<uint64_t>(b, 16, none.size()); // NONE: grid size must equal payload size
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "uncompressed grid size", "differs");
        b = none;
        poke<uint64_t>(b, 16, 100);
        poke<uint64_t>(b, 24, 100);
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "100 bytes", "smaller");
        // read_grid applies the same limits to an entry it is handed.
        nio::GridEntry e = nio::list_grids(none_path)[0];
        e.grid_size = uint64_t(1) << 60;
        CHECK_IO_ERROR(nio::read_grid(none_path, e, nullptr), none_path, "16 GiB");
    }
    SUBCASE("unknown codec") {
        Bytes b = none;
        poke<uint16_t>(b, 14, 7);
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "unknown codec 7");
    }
    SUBCASE("zero grids") {
        Bytes b = none;
        poke<uint16_t>(b, 12, 0);
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "zero grids");
    }
    SUBCASE("trailing garbage after the last segment") {
        Bytes b = none;
        const Bytes junk(40, 0xab);
        b.insert(b.end(), junk.begin(), junk.end());
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "segment 1", "expected a NanoVDB segment header");
    }
    SUBCASE("corrupt zlib stream") {
        Bytes b = zip;
        b[payload + 8] = 0; // zlib header (78 9C)
        b[payload + 9] = 0;
        write(b);
        auto grids = nio::list_grids(p);
        CHECK_IO_ERROR(nio::read_grid(p, grids[0], Aligned(grids[0].grid_size).data()), p,
                       "corrupt zlib stream");
        b = zip;
        for (uint64_t i = payload + 8 + 40; i < payload + 8 + 80; ++i) b[i] ^= 0x5a;
        write(b);
        grids = nio::list_grids(p);
        CHECK_IO_ERROR(nio::read_grid(p, grids[0], Aligned(grids[0].grid_size).data()), p,
                       "zlib");
    }
    SUBCASE("zlib stream decoding to another size than grid_size") {
        Bytes b = zip;
        poke<uint64_t>(b, 16, sphere.size() - 32);
        write(b);
        auto grids = nio::list_grids(p);
        CHECK_IO_ERROR(nio::read_grid(p, grids[0], Aligned(grids[0].grid_size).data()), p,
                       "more than the grid size");
        poke<uint64_t>(b, 16, sphere.size() + 32);
        write(b);
        grids = nio::list_grids(p);
        CHECK_IO_ERROR(nio::read_grid(p, grids[0], Aligned(grids[0].grid_size).data()), p,
                       ("decodes to " + std::to_string(sphere.size())));
    }
    SUBCASE("zlib size prefix larger than the payload") {
        Bytes b = zip;
        poke<uint64_t>(b, payload, uint64_t(1) << 40);
        write(b);
        const auto grids = nio::list_grids(p);
        CHECK_IO_ERROR(nio::read_grid(p, grids[0], Aligned(grids[0].grid_size).data()), p,
                       "truncated payload", "zlib stream");
    }
    SUBCASE("corrupt blosc chunk") {
        Bytes b = blosc;
        for (uint64_t i = payload + 8; i < payload + 8 + 16; ++i) b[i] ^= 0xff; // header
        write(b);
        auto grids = nio::list_grids(p);
        CHECK_IO_ERROR(nio::read_grid(p, grids[0], Aligned(grids[0].grid_size).data()), p,
                       "blosc chunk 0");
        b = blosc;
        poke<uint64_t>(b, 16, sphere.size() + 64); // grid_size disagrees with the chunk
        write(b);
        grids = nio::list_grids(p);
        CHECK_IO_ERROR(nio::read_grid(p, grids[0], Aligned(grids[0].grid_size).data()), p,
                       "blosc chunk 0", "expected");
        b = blosc;
        poke<uint64_t>(b, payload, 3); // chunk smaller than a blosc header
        write(b);
        grids = nio::list_grids(p);
        CHECK_IO_ERROR(nio::read_grid(p, grids[0], Aligned(grids[0].grid_size).data()), p,
                       "smaller than a blosc header");
    }
}

// =====================================================================================
TEST_CASE("the real files in shared/data" * doctest::skip(!fs::is_directory(shared_data_dir()))) {
    const std::string dir = shared_data_dir();
    std::vector<std::string> files;
    for (const auto &entry : fs::directory_iterator(dir))
        if (entry.path().extension() == ".nvdb") files.push_back(entry.path().string());
    std::sort(files.begin(), files.end());
    CHECK(files.size() >= 5);

    SUBCASE("every .nvdb: float grids load, validate and match NanoVDB 32.4's reader") {
        for (const auto &path : files) {
            INFO("file: " << path);
            std::vector<nio::GridEntry> grids;
            CHECK_NOTHROW(grids = nio::list_grids(path));
            for (size_t i = 0; i < grids.size(); ++i) {
                INFO("grid " << i << ": " << grids[i].name);
                if (grids[i].grid_type != 1) {
                    CHECK_IO_ERROR(nio::select_grid(path, grids, std::to_string(i)), path,
                                   nio::grid_type_name(grids[i].grid_type),
                                   "only float grids are supported");
                    continue;
                }
                const auto &e = nio::select_grid(path, grids, std::to_string(i));
                const Aligned buf = load(path, e);
                nio::FloatGridInfo info;
                CHECK_NOTHROW(info = nio::validate_float_grid(path, buf.data(), buf.size));
                // NanoVDB 32.4 reads these files (major 32 only is checked).
                const Handle ref = nanovdb::io::readGrid(path, i);
                CHECK(buf.bytes() == handle_bytes(ref));
                REQUIRE(ref.grid<float>());
                check_info_against_nanovdb(info, *ref.grid<float>());
            }
        }
    }
    SUBCASE("warp torus level set (32.3.3, ZIP)") {
        const std::string path = dir + "/warp_torus_ls_zip_32.3.3.nvdb";
        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 1);
        CHECK(grids[0].name == "surface");
        CHECK(grids[0].version == packed_version(32, 3, 3));
        CHECK(grids[0].codec == nio::Codec::Zip);
        CHECK(grids[0].grid_class == 1); // level set
        const Aligned buf = load(path, nio::select_grid(path, grids, ""));
        const auto info = nio::validate_float_grid(path, buf.data(), buf.size);
        CHECK(info.background == doctest::Approx(0.3f));
        CHECK(info.bbox_min[1] == -5);
        CHECK(info.bbox_max[1] == 5);
        CHECK(info.active_voxel_count == 3001);
        CHECK(info.voxel_size[0] == doctest::Approx(0.1));
    }
    SUBCASE("warp Vec3f and int32 grids (32.3.3, unnamed): clear rejection") {
        for (const auto &[file, type] : { std::make_pair("warp_vec3f_zip_32.3.3.nvdb", "Vec3f"),
                                          std::make_pair("warp_int32_zip_32.3.3.nvdb", "int32") }) {
            const std::string path = dir + "/" + file;
            const auto grids = nio::list_grids(path);
            REQUIRE(grids.size() == 1);
            CHECK(grids[0].name.empty());
            CHECK(nio::grid_type_name(grids[0].grid_type) == type);
            CHECK_IO_ERROR(nio::select_grid(path, grids, ""), path, "no float grid", type);
            CHECK_IO_ERROR(nio::select_grid(path, grids, "0"), path,
                           (std::string("has type ") + type), "only float grids");
            // The payload still decodes and equals NanoVDB's.
            CHECK(load(path, grids[0]).bytes() == handle_bytes(nanovdb::io::readGrid(path, 0)));
        }
    }
    SUBCASE("warp OnIndex grids (32.6.1, two grids in one segment)") {
        const std::string path = dir + "/warp_onindex_2grids_zip_32.6.1.nvdb";
        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 2);
        CHECK(nio::describe_grids(grids) == "0: \"grid-0\" (OnIndex), 1: \"grid-1\" (OnIndex)");
        CHECK(grids[0].version == packed_version(32, 6, 1));
        CHECK(grids[1].segment == 0);
        CHECK_IO_ERROR(nio::select_grid(path, grids, "grid-1"), path, "type OnIndex",
                       "only float grids");
        for (size_t i = 0; i < 2; ++i) {
            const Aligned buf = load(path, grids[i]);
            CHECK(buf.bytes() == handle_bytes(nanovdb::io::readGrid(path, i)));
            CHECK_IO_ERROR(nio::validate_float_grid(path, buf.data(), buf.size), path,
                           "OnIndex", "only float grids");
        }
    }
    SUBCASE("fVDB batch of 4 grids under one metadata entry (32.5.0, BLOSC)") {
        // Reading: the metadata's single grid "z" is the *first* grid of the
        // decoded payload; read_grid returns the whole decoded payload
        // (grid_size bytes, byte-identical to NanoVDB's readGrid), and
        // validate_float_grid uses the first grid's own mGridSize.
        const std::string path = dir + "/fvdb_batch4_ls_blosc_32.5.0.nvdb";
        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 1);
        CHECK(grids[0].name == "z");
        CHECK(grids[0].codec == nio::Codec::Blosc);
        CHECK(grids[0].version == packed_version(32, 5, 0));
        CHECK(grids[0].grid_size == 9243328);
        const Aligned buf = load(path, nio::select_grid(path, grids, "z"));
        const Handle ref = nanovdb::io::readGrid(path, 0);
        CHECK(buf.bytes() == handle_bytes(ref));
        const auto info = nio::validate_float_grid(path, buf.data(), buf.size);
        check_info_against_nanovdb(info, *ref.grid<float>());
        const Bytes all = buf.bytes();
        CHECK(peek<uint64_t>(all, 32) < grids[0].grid_size);
        // Walk the payload: 4 grids back to back, each valid on its own.
        uint64_t offset = 0;
        int count = 0;
        while (offset < all.size() && count < 10) {
            INFO("batch grid " << count << " at byte " << offset);
            CHECK(peek<uint32_t>(all, offset + 24) == uint32_t(count)); // mGridIndex
            CHECK(peek<uint32_t>(all, offset + 28) == 4u);              // mGridCount
            CHECK_NOTHROW(nio::validate_float_grid(path, all.data() + offset, all.size() - offset));
            offset += peek<uint64_t>(all, offset + 32);
            ++count;
        }
        CHECK(count == 4);
        CHECK(offset == all.size());
    }
}

// =====================================================================================
// Values: scan_values() and sanitize_values() (NaN / Inf / negative policy support)
// =====================================================================================

namespace {

/// OpenVDB grid with one chosen value at one level, converted by NanoVDB.
/// level 4: the background; 3: a root tile; 2: an upper-node tile; 1: a
/// lower-node tile; 0: a voxel. Plus an ordinary voxel (5, 5, 5) = 1.
Handle one_value_grid(int level, const openvdb::Coord &ijk, float value) {
    openvdb::initialize();
    auto g = openvdb::FloatGrid::create(level == 4 ? value : 0.f);
    g->setName("one_value");
    g->tree().setValueOn(openvdb::Coord(5, 5, 5), 1.0f);
    if (level >= 1 && level <= 3) g->tree().addTile(level, ijk, value, true);
    if (level == 0) g->tree().setValueOn(ijk, value);
    return nanovdb::openToNanoVDB(*g, nanovdb::StatsMode::Disable);
}

struct Counts { uint64_t nan = 0, posinf = 0, neginf = 0, negative = 0, all = 0; };

/// The same counts through NanoVDB's own node structs (every value a lookup
/// can return, see brute_force()).
Counts brute_counts(const nanovdb::FloatGrid &grid) {
    Counts c;
    auto add = [&](float v) {
        ++c.all;
        if (std::isnan(v)) ++c.nan;
        else if (v == std::numeric_limits<float>::infinity()) ++c.posinf;
        else if (v == -std::numeric_limits<float>::infinity()) ++c.neginf;
        else if (v < 0.f) ++c.negative;
    };
    const auto &tree = grid.tree();
    const auto &root = tree.root();
    add(root.background());
    for (uint32_t i = 0; i < root.tileCount(); ++i)
        if (!root.data()->tile(i)->isChild()) add(root.data()->tile(i)->value);
    const auto *upper = tree.getFirstNode<2>();
    for (uint32_t i = 0; i < tree.nodeCount(2); ++i)
        for (uint32_t n = 0; n < 32768; ++n)
            if (!upper[i].data()->isChild(n)) add(upper[i].data()->getValue(n));
    const auto *lower = tree.getFirstNode<1>();
    for (uint32_t i = 0; i < tree.nodeCount(1); ++i)
        for (uint32_t n = 0; n < 4096; ++n)
            if (!lower[i].data()->isChild(n)) add(lower[i].data()->getValue(n));
    const auto *leaf = tree.getFirstNode<0>();
    for (uint32_t i = 0; i < tree.nodeCount(0); ++i)
        for (uint32_t n = 0; n < 512; ++n) add(leaf[i].getValue(n));
    return c;
}

void check_counts(const nio::ValueScan &s, const nanovdb::FloatGrid &grid) {
    const Counts c = brute_counts(grid);
    CHECK(s.value_count == c.all);
    CHECK(s.nan_count == c.nan);
    CHECK(s.posinf_count == c.posinf);
    CHECK(s.neginf_count == c.neginf);
    CHECK(s.negative_count == c.negative);
    CHECK(s.has_nan == (c.nan > 0));
    CHECK(s.has_inf == (c.posinf + c.neginf > 0));
    CHECK(s.has_negative == (c.negative > 0));
}

std::array<int32_t, 3> xyz(const nio::ValueLocation &l) { return { l.ijk[0], l.ijk[1], l.ijk[2] }; }

} // namespace

TEST_CASE("scan_values: counts, and the coordinate of the first offending value") {
    const float nan = std::numeric_limits<float>::quiet_NaN();
    const float inf = std::numeric_limits<float>::infinity();

    SUBCASE("voxels: NaN, +Inf, -Inf (GridBuilder grid)") {
        const Handle h = nan_inf_grid();
        const auto s = nio::scan_values("nans", h.data(), h.size());
        check_counts(s, *h.grid<float>());
        CHECK(s.nan_count == 2);
        CHECK(s.posinf_count == 1);
        CHECK(s.neginf_count == 1);
        CHECK(s.negative_count == 0);
        REQUIRE(s.has_nan);
        CHECK(s.first_nan.level == 0);
        CHECK(xyz(s.first_nan) == std::array<int32_t, 3>{ 0, 0, 0 });
        CHECK(s.first_nan.reachable);
        REQUIRE(s.has_inf);
        CHECK(xyz(s.first_inf) == std::array<int32_t, 3>{ 2, 0, 0 });
        CHECK(s.finite_max == 4.0f);
        // The byte really holds the value
        float v;
        std::memcpy(&v, reinterpret_cast<const uint8_t *>(h.data()) + s.first_inf.byte, 4);
        CHECK(v == inf);
        CHECK(nio::describe_location(s.first_nan) == "voxel (0, 0, 0)");
        CHECK(nio::describe_invalid_values(s) ==
              "2 NaN (first: voxel (0, 0, 0)), 1 +Inf and 1 -Inf values "
              "(first infinite: voxel (2, 0, 0))");
        // Agrees with validate_float_grid's counts
        const auto info = validate_handle(h, "nans");
        CHECK(info.nan_count == s.nan_count);
        CHECK(info.inf_count == s.posinf_count + s.neginf_count);
    }
    SUBCASE("a NaN at every level, negative coordinates: the lookup's coordinate") {
        struct Case { int level; openvdb::Coord ijk; std::array<int32_t, 3> expect; const char *text; };
        const Case cases[] = {
            { 0, openvdb::Coord(-1, -9, -4097), { -1, -9, -4097 }, "voxel (-1, -9, -4097)" },
            { 1, openvdb::Coord(-9, 130, 7), { -16, 128, 0 },
              "lower-node tile (8^3 voxels) at (-16, 128, 0)" },
            { 2, openvdb::Coord(-300, 5, -5), { -384, 0, -128 },
              "upper-node tile (128^3 voxels) at (-384, 0, -128)" },
            { 3, openvdb::Coord(-5000, 10, 4096), { -8192, 0, 4096 },
              "root tile (4096^3 voxels) at (-8192, 0, 4096)" },
            { 4, openvdb::Coord(0, 0, 0), { 0, 0, 0 }, "background" },
        };
        for (const Case &c : cases) {
            INFO("level " << c.level);
            const Handle h = one_value_grid(c.level, c.ijk, nan);
            const auto s = nio::scan_values("one", h.data(), h.size());
            check_counts(s, *h.grid<float>());
            REQUIRE(s.has_nan);
            CHECK(s.first_nan.level == uint32_t(c.level));
            CHECK(xyz(s.first_nan) == c.expect);
            CHECK(nio::describe_location(s.first_nan) == c.text);
            // NanoVDB's own accessor reads the NaN at the reported coordinate
            if (c.level < 4) {
                auto acc = h.grid<float>()->getAccessor();
                CHECK(std::isnan(acc.getValue(nanovdb::Coord(c.expect[0], c.expect[1], c.expect[2]))));
            }
        }
    }
    SUBCASE("negatives: an inactive upper tile comes before the leaves") {
        const Handle h = tile_grid();
        const auto s = nio::scan_values("tiles", h.data(), h.size());
        check_counts(s, *h.grid<float>());
        CHECK(s.nan_count == 0);
        CHECK(!s.has_inf);
        REQUIRE(s.has_negative);
        CHECK(s.negative_count == 2); // the -50 upper tile and the -2 voxel
        CHECK(s.first_negative.level == 2);
        CHECK(xyz(s.first_negative) == std::array<int32_t, 3>{ 0, 0, 128 });
        CHECK(s.finite_max == 100.0f);
    }
    SUBCASE("a level set's values are negative inside: counted, not an error") {
        const Handle h = ls_torus();
        const auto s = nio::scan_values("torus", h.data(), h.size());
        check_counts(s, *h.grid<float>());
        CHECK(s.negative_count > 0);
        CHECK(s.first_negative.level == 0);
    }
    SUBCASE("clean grid; empty grid with a NaN background") {
        const Handle sphere = fog_sphere();
        const auto s = nio::scan_values("sphere", sphere.data(), sphere.size());
        check_counts(s, *sphere.grid<float>());
        CHECK(!s.has_nan);
        CHECK(!s.has_inf);
        CHECK(!s.has_negative);
        nanovdb::GridBuilder<float> builder(nan, nanovdb::GridClass::FogVolume);
        const Handle e = builder.getHandle(1.0, nanovdb::Vec3d(0), "empty_nan");
        const auto se = nio::scan_values("empty", e.data(), e.size());
        CHECK(se.value_count == 1);
        CHECK(se.nan_count == 1);
        CHECK(se.first_nan.level == 4);
        CHECK(se.finite_max == -inf);
    }
    SUBCASE("a node no root tile reaches: scanned, flagged unreachable") {
        // Turn the root tile that leads to the sphere's only upper node into a
        // value tile: the upper node (and everything below) is unreachable.
        const Handle sphere = fog_sphere();
        Bytes b = handle_bytes(sphere);
        const auto &grid = *sphere.grid<float>();
        const auto &root = grid.tree().root();
        REQUIRE(grid.tree().nodeCount(2) >= 1);
        const uint64_t leaf0 = offset_in(grid, grid.tree().getFirstNode<0>());
        poke<float>(b, leaf0 + 96 + 4 * 17, nan); // a NaN in the first leaf
        const auto before = nio::scan_values("b", b.data(), b.size());
        REQUIRE(before.has_nan);
        CHECK(before.first_nan.reachable);
        for (uint32_t i = 0; i < root.tileCount(); ++i)
            poke<int64_t>(b, offset_in(grid, root.data()->tile(i)) + 8, 0);
        const auto after = nio::scan_values("b", b.data(), b.size());
        REQUIRE(after.has_nan);
        CHECK(!after.first_nan.reachable);
        CHECK(xyz(after.first_nan) == xyz(before.first_nan));
        CHECK(nio::describe_location(after.first_nan).find("no root tile reaches") !=
              std::string::npos);
    }
    SUBCASE("invalid buffers: the validator's errors") {
        const Handle sphere = fog_sphere();
        Bytes b = handle_bytes(sphere);
        poke<uint64_t>(b, 672 + 24, b.size()); // root offset outside
        CHECK_IO_ERROR(nio::scan_values("bad", b.data(), b.size()), "bad", "root node offset");
        CHECK_IO_ERROR(nio::sanitize_values("bad", b.data(), b.size()), "bad", "root node offset");
    }
}

TEST_CASE("sanitize_values replaces NaN, Inf and negatives in place") {
    const float inf = std::numeric_limits<float>::infinity();
    SUBCASE("NaN -> 0, +Inf -> largest finite value, -Inf -> 0") {
        const Handle h = nan_inf_grid();
        Aligned a(h.size());
        std::memcpy(a.data(), h.data(), h.size());
        const auto r = nio::sanitize_values("nans", a.data(), a.size);
        CHECK(r.nan == 2);
        CHECK(r.posinf == 1);
        CHECK(r.neginf == 1);
        CHECK(r.negative == 0);
        CHECK(r.total() == 4);
        const auto info = nio::validate_float_grid("nans", a.data(), a.size);
        CHECK(info.nan_count == 0);
        CHECK(info.inf_count == 0);
        CHECK(info.value_max == 4.0f);
        CHECK(info.value_min == 0.0f);
        // Read back with NanoVDB's accessor
        const auto *g = reinterpret_cast<const nanovdb::FloatGrid *>(a.data());
        auto acc = g->getAccessor();
        CHECK(acc.getValue(nanovdb::Coord(0, 0, 0)) == 0.0f);
        CHECK(acc.getValue(nanovdb::Coord(1, 0, 0)) == 0.0f);
        CHECK(acc.getValue(nanovdb::Coord(2, 0, 0)) == 4.0f);
        CHECK(acc.getValue(nanovdb::Coord(3, 0, 0)) == 4.0f);
        CHECK(acc.getValue(nanovdb::Coord(300, 0, 0)) == 0.0f);
        // Only those 4 values changed
        Bytes before = handle_bytes(h), after = a.bytes();
        size_t changed_words = 0;
        for (size_t i = 0; i < before.size(); i += 4)
            changed_words += std::memcmp(&before[i], &after[i], 4) != 0;
        CHECK(changed_words == 4);
        // Idempotent
        CHECK(nio::sanitize_values("nans", a.data(), a.size).total() == 0);
    }
    SUBCASE("negatives: clamped to 0, or kept (then -Inf -> the lowest finite value)") {
        const Handle h = one_value_grid(2, openvdb::Coord(-300, 5, -5), -inf);
        Aligned a(h.size()), k(h.size());
        std::memcpy(a.data(), h.data(), h.size());
        std::memcpy(k.data(), h.data(), h.size());
        const Handle t = tile_grid();
        Aligned ta(t.size());
        std::memcpy(ta.data(), t.data(), t.size());
        const auto rt = nio::sanitize_values("tiles", ta.data(), ta.size);
        CHECK(rt.negative == 2);
        const auto it = nio::validate_float_grid("tiles", ta.data(), ta.size);
        CHECK(it.value_min == 0.0f);
        CHECK(it.value_max == 100.0f);
        CHECK(nio::scan_values("tiles", ta.data(), ta.size).negative_count == 0);

        nio::SanitizeOptions keep;
        keep.clamp_negative = false;
        Aligned tk(t.size());
        std::memcpy(tk.data(), t.data(), t.size());
        CHECK(nio::sanitize_values("tiles", tk.data(), tk.size, keep).total() == 0);
        CHECK(tk.bytes() == handle_bytes(t));

        const auto r = nio::sanitize_values("neg", k.data(), k.size, keep);
        CHECK(r.neginf == 1);
        const auto *g = reinterpret_cast<const nanovdb::FloatGrid *>(k.data());
        CHECK(g->getAccessor().getValue(nanovdb::Coord(-300, 5, -5)) == 0.0f); // lowest finite: 0
        CHECK(nio::sanitize_values("neg", a.data(), a.size).neginf == 1);
        CHECK(reinterpret_cast<const nanovdb::FloatGrid *>(a.data())
                  ->getAccessor().getValue(nanovdb::Coord(-300, 5, -5)) == 0.0f);
    }
    SUBCASE("only invalid values: +Inf -> 0") {
        nanovdb::GridBuilder<float> builder(std::numeric_limits<float>::quiet_NaN(),
                                            nanovdb::GridClass::FogVolume);
        builder.setStats(nanovdb::StatsMode::Disable);
        auto acc = builder.getAccessor();
        for (int i = 0; i < 8; ++i)
            for (int j = 0; j < 8; ++j)
                for (int k = 0; k < 8; ++k) acc.setValue(nanovdb::Coord(i, j, k), inf);
        const Handle h = builder.getHandle(1.0, nanovdb::Vec3d(0), "all_inf");
        Aligned a(h.size());
        std::memcpy(a.data(), h.data(), h.size());
        nio::sanitize_values("allinf", a.data(), a.size);
        const auto info = nio::validate_float_grid("allinf", a.data(), a.size);
        CHECK(info.value_min == 0.0f);
        CHECK(info.value_max == 0.0f);
    }
}

// =====================================================================================
TEST_CASE("validate_float_grid: node arrays must not overlap; children at the right level") {
    const Handle sphere = fog_sphere();
    const auto &grid = *sphere.grid<float>();
    const auto &tree = grid.tree();
    const Bytes good = handle_bytes(sphere);
    const std::string p = "overlap.nvdb";
    const uint64_t tree_off = 672;
    const uint64_t root_off = offset_in(grid, &tree.root());
    const uint64_t upper0 = offset_in(grid, tree.getFirstNode<2>());
    const uint64_t lower0 = offset_in(grid, tree.getFirstNode<1>());
    auto validate = [&](const Bytes &b) { return nio::validate_float_grid(p, b.data(), b.size()); };

    SUBCASE("the leaf array overlapping the root") {
        Bytes b = good;
        poke<uint64_t>(b, tree_off + 0, root_off - tree_off);
        CHECK_IO_ERROR(validate(b), p, "leaf node array", "overlaps the root node");
    }
    SUBCASE("the lower array overlapping the upper array") {
        Bytes b = good;
        poke<uint64_t>(b, tree_off + 8, upper0 - tree_off + 32);
        CHECK_IO_ERROR(validate(b), p, "lower node array", "overlaps the upper node array");
    }
    SUBCASE("a node array inside the grid header") {
        Bytes b = good;
        poke<uint64_t>(b, tree_off + 16, 0); // upper array at the tree itself
        CHECK_IO_ERROR(validate(b), p, "upper node array", "overlaps the grid and tree header");
    }
    SUBCASE("a root table long enough to run into the upper array") {
        Bytes b = good;
        const uint32_t tiles = uint32_t((upper0 - root_off - 64) / 32) + 1;
        poke<uint32_t>(b, root_off + 24, tiles);
        CHECK_IO_ERROR(validate(b), p, "upper node array", "overlaps the root node and its tile table");
    }
    SUBCASE("child offsets at the parent itself, backwards, or at the wrong level") {
        const auto *upper = tree.getFirstNode<2>();
        uint32_t n = 0;
        while (n < 32768 && !upper->childMask().isOn(n)) ++n;
        REQUIRE(n < 32768);
        const uint64_t entry = upper0 + 8256 + 8 * n;
        Bytes b = good;
        poke<int64_t>(b, entry, 0); // the upper node itself
        CHECK_IO_ERROR(validate(b), p, "upper node 0", "outside the lower node array");
        poke<int64_t>(b, entry, int64_t(root_off) - int64_t(upper0)); // backwards, at the root
        CHECK_IO_ERROR(validate(b), p, "upper node 0", "outside the lower node array");
        // A root tile pointing at a lower node (one level too deep)
        uint32_t t = 0;
        const auto &root = tree.root();
        while (!root.data()->tile(t)->isChild()) ++t;
        Bytes c = good;
        poke<int64_t>(c, offset_in(grid, root.data()->tile(t)) + 8, int64_t(lower0) - int64_t(root_off));
        CHECK_IO_ERROR(validate(c), p, "root tile", "outside the upper node array");
    }
    SUBCASE("every file of shared/data and every NanoVDB-made grid still validates") {
        for (const Handle *h : { &sphere }) CHECK_NOTHROW(validate_handle(*h, "ok"));
        const Handle t = tile_grid(), e = empty_grid(), l = ls_torus();
        CHECK_NOTHROW(validate_handle(t, "t"));
        CHECK_NOTHROW(validate_handle(e, "e"));
        CHECK_NOTHROW(validate_handle(l, "l"));
    }
}

// =====================================================================================
// A buffer that passed validation but holds garbage (mutated tile keys, masks,
// table values, counts...) never makes a lookup leave it. The grid sits at the
// end of a mapping followed by 16 GiB + a page of PROT_NONE address space, all
// that a 32-bit word address can reach: any read past the end faults. Each
// returned address is also checked against the buffer size.
// =====================================================================================

namespace {

struct Guarded {
    uint8_t *base = nullptr, *data = nullptr;
    size_t total = 0;
    explicit Guarded(uint64_t bytes) {
        const size_t page = size_t(sysconf(_SC_PAGESIZE));
        const size_t rounded = size_t((bytes + 31) / 32 * 32);
        const size_t head = (rounded + page - 1) / page * page;
        total = head + (size_t(1) << 34) + page;
        void *p = mmap(nullptr, total, PROT_NONE, MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
        REQUIRE(p != MAP_FAILED);
        base = static_cast<uint8_t *>(p);
        REQUIRE(mprotect(base, head, PROT_READ | PROT_WRITE) == 0);
        data = base + head - rounded;
    }
    ~Guarded() { munmap(base, total); }
};

} // namespace

TEST_CASE("validated but garbage buffers: lookups never leave the buffer") {
    namespace ndr = nanovdb_drjit;
    const Handle grids[] = { fog_sphere(), tile_grid(), nan_inf_grid() };
    std::mt19937_64 rng(5);
    uint64_t valid = 0, lookups = 0;
    for (const Handle &h : grids) {
        const auto &grid = *h.grid<float>();
        const uint64_t size = h.size();
        Guarded g(size);
        std::memcpy(g.data, h.data(), size);
        const uint64_t words = (size + 3) / 4;
        const uint64_t tree_end = 736;
        for (int m = 0; m < 1500; ++m) {
            // Mutate a few bytes anywhere past the grid header (tree header
            // included); remember them to restore afterwards.
            std::vector<std::pair<uint64_t, uint8_t>> saved;
            const int k = 1 + int(rng() % 8);
            for (int i = 0; i < k; ++i) {
                uint64_t off = 672 + rng() % (size - 672);
                if (rng() % 4 == 0) off = 672 + rng() % (tree_end - 672 + 600); // header, root, tiles
                saved.push_back({ off, g.data[off] });
                g.data[off] = uint8_t(rng() % 3 == 0 ? g.data[off] ^ (1u << (rng() % 8)) : rng());
            }
            nio::FloatGridInfo info;
            bool ok = true;
            try {
                info = nio::validate_float_grid("mutant", g.data, size);
            } catch (const nio::Error &) {
                ok = false;
            }
            if (ok) {
                ++valid;
                const uint32_t *buf = reinterpret_cast<const uint32_t *>(g.data);
                ndr::RootHandle<uint32_t> root{ info.root_word };
                for (int q = 0; q < 64; ++q) {
                    int32_t c[3];
                    for (int a = 0; a < 3; ++a) {
                        const uint64_t r = rng();
                        // near the bbox minimum (INT32_MAX for an empty bbox: wrap)
                        c[a] = (r & 1) ? int32_t(r >> 32)
                                       : int32_t(uint32_t(grid.indexBBox().min()[a]) +
                                                 uint32_t((r >> 8) % 300) - 100u);
                        if (c[a] == INT32_MAX) c[a] = 0;
                    }
                    ndr::Coord<uint32_t> ijk(c[0], c[1], c[2]);
                    const uint32_t a = ndr::root_get_value_address(buf, root, ijk, true);
                    const auto st = ndr::root_get_stencil_addresses(buf, root, ijk, true);
                    bool inside = a < words;
                    for (int s = 0; s < 8; ++s) inside &= st[s] < words;
                    if (!inside) {
                        INFO("mutant " << m << " ijk " << c[0] << " " << c[1] << " " << c[2]);
                        CHECK(inside);
                    }
                    ++lookups;
                }
                (void) nio::scan_values("mutant", g.data, size);
            }
            for (auto it = saved.rbegin(); it != saved.rend(); ++it) g.data[it->first] = it->second;
        }
    }
    MESSAGE(valid, " of 4500 mutated buffers validated; ", lookups,
            " lookups (1 + 8 addresses each) stayed inside");
    CHECK(valid > 500);
}
