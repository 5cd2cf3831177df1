// tests/io/fixtures.h -- what the loader tests (tests/io/test_*.cpp) share:
// files and buffers, the error-message check, and test grids built with
// NanoVDB's and OpenVDB's own APIs (the independent references).
//
// The independent references are NanoVDB 32.4's own C++ API (Debian's
// libnanovdb-dev): its writer (nanovdb::io::writeGrid/writeGrids with the
// NONE, ZIP and BLOSC codecs), its reader (nanovdb::io::readGrid), its grid
// builders and its node structs, plus OpenVDB 10 for grids with tiles at
// every level. Newer file forms (32.6+ raw grid buffers, 32.8+ "NanoVDB2" /
// "NanoVDB1" magics) are hand-built from files the 32.4 writer made. Hostile
// inputs are made by patching such files at offsets located with the NanoVDB
// API. The real files in ../shared/data are read in place.
#pragma once

#include <doctest/doctest.h>

#include <nanovdb/NanoVDB.h>
#include <nanovdb/util/GridBuilder.h>
#include <nanovdb/util/IO.h>
#include <nanovdb/util/OpenToNanoVDB.h>
#include <nanovdb/util/Primitives.h>
#include <openvdb/openvdb.h>

#include <nanovdb_loader/container.h>
#include <nanovdb_loader/validation.h>
#include <nanovdb_loader/values.h>


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

namespace nio = nanovdb_loader;
namespace fs = std::filesystem;
using Bytes = std::vector<uint8_t>;
using Handle = nanovdb::GridHandle<nanovdb::HostBuffer>;

namespace nvdb_io_test {

/// The real volumes from other tools: $NVDB_SHARED_DATA, by default
/// ../shared/data beside the repository. Tests that need them are skipped
/// when the folder is absent.
inline std::string shared_data_dir() {
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

inline std::string tmp_path(const std::string &name) {
    static TempDir tmp;
    return (tmp.dir / name).string();
}

inline Bytes read_bytes(const std::string &path) {
    std::ifstream in(path, std::ios::binary);
    return Bytes(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

inline void write_bytes(const std::string &path, const Bytes &b) {
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

inline Bytes handle_bytes(const Handle &h) {
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

inline Aligned load(const std::string &path, const nio::GridEntry &e) {
    Aligned a(e.grid_size);
    nio::read_grid(path, e, a.data());
    return a;
}

inline uint32_t packed_version(uint32_t major, uint32_t minor, uint32_t patch) {
    return major << 21 | minor << 10 | patch;
}

// ---- Error checks -------------------------------------------------------------------

inline std::string error_of(const std::function<void()> &f) {
    try {
        f();
    } catch (const nio::Error &e) {
        return e.what();
    } catch (const std::exception &e) {
        return std::string("<wrong exception type, not io::Error> ") + e.what();
    }
    return "<no exception>";
}

inline void check_message(const std::string &msg, const std::string &path,
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

inline Handle fog_sphere(const std::string &name = "density") {
    return nanovdb::createFogVolumeSphere<float>(12.0f, nanovdb::Vec3f(1, 2, 3), 0.5, 3.0,
                                                 nanovdb::Vec3d(0.25, -1.0, 2.0), name);
}

inline Handle ls_torus(const std::string &name = "surface") {
    return nanovdb::createLevelSetTorus<float>(20.0f, 6.0f, nanovdb::Vec3f(0), 1.0, 3.0,
                                               nanovdb::Vec3d(0), name);
}

/// Float grid with tiles at every level (root tile, upper tile, lower tile)
/// whose values are the extremes: value_max = 100 (root tile), value_min = -50
/// (an inactive upper-node tile). Built with OpenVDB, converted by NanoVDB.
inline Handle tile_grid() {
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
inline Handle nan_inf_grid() {
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

inline Handle empty_grid() {
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

inline Brute brute_force(const nanovdb::FloatGrid &grid) {
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

/// validate_grid's summary against the NanoVDB C++ API.
inline void check_info_against_nanovdb(const nio::ValidatedGrid &validated,
                                       const nanovdb::FloatGrid &grid) {
    const nio::GridSummary &info = validated.summary();
    const nio::ValueStats &values = validated.values();
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
    CHECK(values.nan_count == b.nan);
    CHECK(values.inf_count() == b.inf);
    CHECK(values.value_count == b.nan + b.seen);
    if (b.seen > 0) {
        CHECK(values.min == b.vmin);
        CHECK(values.max == b.vmax);
    } else {
        CHECK(std::isnan(values.min));
        CHECK(std::isnan(values.max));
    }
}

inline nio::ValidatedGrid validate_handle(const Handle &h, const std::string &label) {
    return nio::validate_grid(label, h.data(), h.size());
}

/// validate + scan_values, for buffers the test has at hand
inline nio::ValueScan scan(const std::string &path, const void *data, uint64_t bytes) {
    return nio::scan_values(nio::validate_grid(path, data, bytes));
}

/// validate + sanitize_values, in place
inline nio::SanitizeResult sanitize(const std::string &path, void *data, uint64_t bytes,
                                    const nio::SanitizeOptions &options = {}) {
    nio::ValidatedGrid grid = nio::validate_grid(path, data, bytes);
    return nio::sanitize_values(grid, options);
}

// Offsets (in the grid buffer) of NanoVDB structures, found with its API.
template <typename T> uint64_t offset_in(const nanovdb::FloatGrid &grid, const T *p) {
    return uint64_t(reinterpret_cast<const uint8_t *>(p) -
                    reinterpret_cast<const uint8_t *>(&grid));
}

} // namespace nvdb_io_test

using namespace nvdb_io_test;
