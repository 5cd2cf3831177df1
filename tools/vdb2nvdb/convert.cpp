// vdb2nvdb: conversion (NanoVDB's own nanovdb::OpenToNanoVDB), verification
// against OpenVDB, statistics and the dense .vol export. See convert.h.

#include "convert.h"

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cfloat>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <set>
#include <sstream>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <openvdb/io/Stream.h>
#include <openvdb/tools/LevelSetUtil.h>
#include <nanovdb/util/GridChecksum.h>
#include <nanovdb/util/GridValidator.h>
#include <nanovdb/util/NanoToOpenVDB.h>
#include <nanovdb/util/OpenToNanoVDB.h>

namespace vdb2nvdb {

namespace fs = std::filesystem;
using openvdb::Coord;
using openvdb::CoordBBox;
using openvdb::FloatGrid;
using Clock = std::chrono::steady_clock;

// ---------------------------------------------------------------------------
//  Formatting helpers
// ---------------------------------------------------------------------------

namespace {

std::string dq(const std::string &s) { return "\"" + s + "\""; }

std::string fmt_count(uint64_t n) {
    std::string s = std::to_string(n), out;
    for (size_t i = 0; i < s.size(); ++i) {
        if (i > 0 && (s.size() - i) % 3 == 0)
            out += ',';
        out += s[i];
    }
    return out;
}

std::string fmt_bytes(uint64_t n) {
    char buf[64];
    if (n >= (uint64_t(1) << 30))
        std::snprintf(buf, sizeof(buf), " (%.2f GiB)", double(n) / double(1u << 30));
    else if (n >= (uint64_t(1) << 20))
        std::snprintf(buf, sizeof(buf), " (%.1f MiB)", double(n) / double(1u << 20));
    else if (n >= 1024)
        std::snprintf(buf, sizeof(buf), " (%.1f KiB)", double(n) / 1024.0);
    else
        buf[0] = '\0';
    return fmt_count(n) + " B" + buf;
}

std::string fmt_coord(const Coord &c) {
    return "(" + std::to_string(c.x()) + ", " + std::to_string(c.y()) + ", " +
           std::to_string(c.z()) + ")";
}

std::string fmt_float(double v) {
    char buf[64];
    std::snprintf(buf, sizeof(buf), "%.9g", v);
    return buf;
}

double ms_since(Clock::time_point t0) {
    return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

std::string class_name(openvdb::GridClass c) {
    return openvdb::GridBase::gridClassToString(c);
}

/// "name" (type, class)
std::string grid_summary(const openvdb::GridBase &g) {
    return dq(g.getName()) + " (" + g.valueType() + ", " + class_name(g.getGridClass()) + ")";
}

std::string list_grids(const openvdb::GridPtrVec &grids) {
    std::string s;
    for (const auto &g : grids)
        s += (s.empty() ? "" : ", ") + grid_summary(*g);
    return s.empty() ? "(no grids)" : s;
}

/// A file name made of a grid name: [A-Za-z0-9._-], others become '_'.
std::string safe_name(const std::string &name, size_t index) {
    if (name.empty())
        return "grid" + std::to_string(index);
    std::string s = name;
    for (char &c : s)
        if (!std::isalnum((unsigned char) c) && c != '.' && c != '-' && c != '_')
            c = '_';
    return s;
}

/// splitmix64: deterministic on every platform (no std:: distributions).
struct Rng {
    uint64_t state;
    explicit Rng(uint64_t seed) : state(seed * 0x9E3779B97F4A7C15ull + 0x632BE59BD9B4E019ull) {}
    uint64_t next() {
        uint64_t z = (state += 0x9E3779B97F4A7C15ull);
        z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
        z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
        return z ^ (z >> 31);
    }
    uint64_t below(uint64_t n) { return n ? next() % n : 0; }
    /// Uniform integer in [lo, hi] (inclusive)
    int32_t range(int64_t lo, int64_t hi) { return int32_t(lo + int64_t(below(uint64_t(hi - lo) + 1))); }
};

void say(const Options &opts, const std::string &msg) {
    if (!opts.quiet)
        std::printf("%s\n", msg.c_str());
    std::fflush(stdout);
}

void note(const std::string &msg) {
    std::fflush(stdout);
    std::fprintf(stderr, "vdb2nvdb: note: %s\n", msg.c_str());
}

uint32_t float_bits(float v) {
    uint32_t u;
    std::memcpy(&u, &v, 4);
    return u;
}

} // namespace

const char *quantize_name(Quantize q) {
    switch (q) {
        case Quantize::Float: return "float";
        case Quantize::Fp4: return "fp4";
        case Quantize::Fp8: return "fp8";
        case Quantize::Fp16: return "fp16";
        case Quantize::FpN: return "fpn";
    }
    return "?";
}

uint64_t physical_memory() {
    long pages = sysconf(_SC_PHYS_PAGES), size = sysconf(_SC_PAGE_SIZE);
    return (pages > 0 && size > 0) ? uint64_t(pages) * uint64_t(size) : 0;
}

// ---------------------------------------------------------------------------
//  Temporary output files
// ---------------------------------------------------------------------------

namespace {
constexpr int kMaxTemps = 256;
char g_temp_paths[kMaxTemps][4096];
volatile std::sig_atomic_t g_temp_live[kMaxTemps];

extern "C" void on_fatal_signal(int sig) {
    for (int i = 0; i < kMaxTemps; ++i)
        if (g_temp_live[i])
            ::unlink(g_temp_paths[i]);
    std::signal(sig, SIG_DFL);
    std::raise(sig);
}
} // namespace

void install_signal_handlers() {
    std::signal(SIGINT, on_fatal_signal);
    std::signal(SIGTERM, on_fatal_signal);
    std::signal(SIGHUP, on_fatal_signal);
}

TempFile::TempFile(const std::string &path) : m_path(path) {
    if (path.empty())
        throw Error("empty output file name");
    fs::path p(path);
    std::error_code ec;
    if (fs::is_directory(p, ec))
        throw Error(dq(path) + ": is a directory; give an output file name");
    if (!p.has_filename())
        throw Error(dq(path) + ": not a file name");
    fs::path dir = p.has_parent_path() ? p.parent_path() : fs::path(".");
    std::string templ = (dir / ("." + p.filename().string() + ".tmp-XXXXXX")).string();
    std::vector<char> buf(templ.begin(), templ.end());
    buf.push_back('\0');
    int fd = ::mkstemp(buf.data());
    if (fd < 0)
        throw Error("cannot write " + dq(path) + ": cannot create a file in " +
                    dq(dir.string()) + ": " + std::strerror(errno));
    // mkstemp creates mode 0600; give the file the usual 0666 & ~umask
    mode_t mask = ::umask(0);
    ::umask(mask);
    (void) ::fchmod(fd, 0666 & ~mask);
    ::close(fd);
    m_tmp = buf.data();
    if (m_tmp.size() < sizeof(g_temp_paths[0])) {
        for (int i = 0; i < kMaxTemps; ++i)
            if (!g_temp_live[i]) {
                std::memcpy(g_temp_paths[i], m_tmp.c_str(), m_tmp.size() + 1);
                g_temp_live[i] = 1;
                m_slot = i;
                break;
            }
    }
}

void TempFile::commit() {
    if (m_done)
        return;
    if (std::rename(m_tmp.c_str(), m_path.c_str()) != 0) {
        int err = errno;
        discard();
        throw Error("cannot write " + dq(m_path) + ": " + std::strerror(err));
    }
    m_done = true;
    if (m_slot >= 0)
        g_temp_live[m_slot] = 0;
}

void TempFile::discard() {
    if (m_done)
        return;
    ::unlink(m_tmp.c_str());
    m_done = true;
    if (m_slot >= 0)
        g_temp_live[m_slot] = 0;
}

TempFile::~TempFile() { discard(); }

// ---------------------------------------------------------------------------
//  Reading .vdb files
// ---------------------------------------------------------------------------

openvdb::GridPtrVec read_vdb(const std::string &path) {
    std::error_code ec;
    if (!fs::exists(path, ec))
        throw Error(dq(path) + ": no such file");
    if (fs::is_directory(path, ec))
        throw Error(dq(path) + ": is a directory, not a .vdb file");
    try {
        // io::Stream reads the grids in file order (io::File::getGrids()
        // returns them sorted by name).
        std::ifstream is(path, std::ios::binary);
        if (!is)
            throw Error(dq(path) + ": cannot open: " + std::strerror(errno));
        openvdb::io::Stream stream(is, /*delayLoad=*/false);
        openvdb::GridPtrVecPtr grids = stream.getGrids();
        if (!grids)
            throw Error(dq(path) + ": cannot read as an OpenVDB file: no grids read");
        return *grids;
    } catch (const openvdb::Exception &e) {
        throw Error(dq(path) + ": cannot read as an OpenVDB file: " + e.what());
    } catch (const std::exception &e) {
        throw Error(dq(path) + ": cannot read as an OpenVDB file (corrupt or truncated?): " +
                    e.what());
    }
}

/// A .nvdb file's grids as OpenVDB grids, through NanoVDB's own reader and
/// nanoToOpenVDB: a NanoVDB level set can then become a fog volume as an
/// OpenVDB one does (nanovdb-render does that with .nvdb level sets). Grids
/// that NanoVDB cannot turn back into OpenVDB grids (index grids, points)
/// are skipped with a note.
openvdb::GridPtrVec read_nvdb(const std::string &path) {
    std::error_code ec;
    if (!fs::exists(path, ec))
        throw Error(dq(path) + ": no such file");
    std::vector<nanovdb::GridHandle<nanovdb::HostBuffer>> handles;
    try {
        handles = nanovdb::io::readGrids<nanovdb::HostBuffer>(path);
    } catch (const std::exception &e) {
        throw Error(dq(path) + ": cannot read as a NanoVDB file (NanoVDB " +
                    std::to_string(NANOVDB_MAJOR_VERSION_NUMBER) + "." +
                    std::to_string(NANOVDB_MINOR_VERSION_NUMBER) + "'s reader): " + e.what());
    }
    openvdb::GridPtrVec grids;
    for (size_t i = 0; i < handles.size(); ++i) {
        const nanovdb::GridMetaData *m = handles[i].gridMetaData();
        const std::string name = m ? m->shortGridName() : std::to_string(i);
        try {
            grids.push_back(nanovdb::nanoToOpenVDB(handles[i]));
        } catch (const std::exception &e) {
            std::string type = m ? nanovdb::toStr(m->gridType()) : "?";
            if (type == "End") // a type newer than this NanoVDB (OnIndex, ...)
                type = "grid type " + std::to_string(uint32_t(m->gridType()));
            note(dq(path) + ": grid " + dq(name) + " (" + type + "): not read: " + e.what());
        }
    }
    if (grids.empty())
        throw Error(dq(path) + ": no grid that NanoVDB can read back into OpenVDB");
    return grids;
}

openvdb::GridPtrVec read_input(const std::string &path) {
    const bool nvdb = path.size() >= 5 && path.compare(path.size() - 5, 5, ".nvdb") == 0;
    return nvdb ? read_nvdb(path) : read_vdb(path);
}

/// "[(x, y, z), (x, y, z)]" of a world-space box
std::string fmt_world_box(const openvdb::math::BBox<openvdb::Vec3d> &b) {
    char s[200];
    std::snprintf(s, sizeof(s), "[(%g, %g, %g), (%g, %g, %g)]", b.min()[0], b.min()[1], b.min()[2],
                  b.max()[0], b.max()[1], b.max()[2]);
    return s;
}

/// The lines under a grid's row in --list: where it lies in world space (the
/// active voxels' cells through the transform), the transform, the values
std::string grid_details(const openvdb::GridBase &g, const CoordBBox &box) {
    std::string out;
    const openvdb::math::Transform &xf = g.transform();
    char line[400];
    if (!box.empty()) {
        openvdb::math::BBox<openvdb::Vec3d> wb;
        for (int c = 0; c < 8; ++c)
            wb.expand(xf.indexToWorld(openvdb::Vec3d((c & 1) ? box.max().x() + 0.5 : box.min().x() - 0.5,
                                                     (c & 2) ? box.max().y() + 0.5 : box.min().y() - 0.5,
                                                     (c & 4) ? box.max().z() + 0.5 : box.min().z() - 0.5)));
        const openvdb::Vec3d ext = wb.extents();
        std::snprintf(line, sizeof(line), "      world bbox %s, size %g x %g x %g\n",
                      fmt_world_box(wb).c_str(), ext[0], ext[1], ext[2]);
        out += line;
    }
    const openvdb::Vec3d t = xf.indexToWorld(openvdb::Vec3d(0.0));
    const bool linear = xf.baseMap()->isLinear();
    bool axis_aligned = linear;
    if (linear) {
        const openvdb::Mat4d m = xf.baseMap()->getAffineMap()->getMat4();
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c)
                axis_aligned &= r == c || m(r, c) == 0.0;
    }
    std::snprintf(line, sizeof(line),
                  "      transform %s: translation (%g, %g, %g), voxel size (%g, %g, %g), %s\n",
                  xf.mapType().c_str(), t[0], t[1], t[2], g.voxelSize()[0], g.voxelSize()[1],
                  g.voxelSize()[2],
                  !linear ? "not affine (NanoVDB cannot represent it)"
                          : axis_aligned ? "no rotation" : "rotated or sheared");
    out += line;
    auto range = [&](const auto &grid, auto &&value_of) {
        double lo = 0, hi = 0;
        bool any = false;
        for (auto it = grid.cbeginValueOn(); it; ++it) {
            const double v = value_of(*it);
            lo = any ? std::min(lo, v) : v;
            hi = any ? std::max(hi, v) : v;
            any = true;
        }
        if (!any)
            return std::string("      active values: none\n");
        char l[160];
        std::snprintf(l, sizeof(l), "      active values in [%g, %g]\n", lo, hi);
        return std::string(l);
    };
    if (auto f = dynamic_cast<const FloatGrid *>(&g))
        out += range(*f, [](float v) { return double(v); });
    else if (auto v = dynamic_cast<const openvdb::Vec3SGrid *>(&g)) {
        std::string r = range(*v, [](const openvdb::Vec3s &x) {
            return double(std::max(x[0], std::max(x[1], x[2])));
        });
        const size_t at = r.find("active values");
        if (at != std::string::npos)
            r.replace(at, 13, "active values' largest channel");
        out += r;
    }
    return out;
}

int list_file(const std::string &in) {
    openvdb::GridPtrVec grids = read_input(in);
    std::printf("%s: %zu grid%s\n", in.c_str(), grids.size(), grids.size() == 1 ? "" : "s");
    std::printf("  %-3s %-20s %-12s %-11s %15s  %-44s %s\n", "#", "name", "type", "class",
                "active voxels", "active index bbox [min, max]", "voxel size");
    for (size_t i = 0; i < grids.size(); ++i) {
        const auto &g = *grids[i];
        CoordBBox box = g.evalActiveVoxelBoundingBox();
        std::string bbox = box.empty() ? "(empty)"
                                       : "[" + fmt_coord(box.min()) + ", " + fmt_coord(box.max()) + "]";
        openvdb::Vec3d vs = g.voxelSize();
        char vsz[96];
        if (vs[0] == vs[1] && vs[1] == vs[2])
            std::snprintf(vsz, sizeof(vsz), "%g", vs[0]);
        else
            std::snprintf(vsz, sizeof(vsz), "%g x %g x %g", vs[0], vs[1], vs[2]);
        std::printf("  %-3zu %-20s %-12s %-11s %15s  %-44s %s\n", i, dq(g.getName()).c_str(),
                    g.valueType().c_str(), class_name(g.getGridClass()).c_str(),
                    fmt_count(g.activeVoxelCount()).c_str(), bbox.c_str(), vsz);
        std::printf("%s", grid_details(g, box).c_str());
    }
    return ExitOk;
}

// ---------------------------------------------------------------------------
//  Selecting and preparing grids
// ---------------------------------------------------------------------------

namespace {

struct Prepared {
    FloatGrid::Ptr grid;        ///< after the fog conversion, if any (null: a vec3s grid)
    openvdb::Vec3SGrid::Ptr vec; ///< a vec3s grid: written as Vec3f, never quantized
    std::string name;

    const openvdb::GridBase &base() const {
        return vec ? static_cast<const openvdb::GridBase &>(*vec)
                   : static_cast<const openvdb::GridBase &>(*grid);
    }
    openvdb::GridClass source_class;
    bool fogged = false;
};

std::vector<Prepared> select_and_prepare(openvdb::GridPtrVec &all, const std::string &label,
                                         const Options &opts) {
    std::vector<bool> chosen(all.size(), false);
    if (!opts.grids.empty()) {
        for (const std::string &name : opts.grids) {
            bool found = false;
            for (size_t i = 0; i < all.size(); ++i) {
                if (all[i]->getName() != name)
                    continue;
                found = true;
                if (!all[i]->isType<FloatGrid>() && !all[i]->isType<openvdb::Vec3SGrid>())
                    throw Error(label + ": grid " + grid_summary(*all[i]) +
                                " cannot be converted: only float and vec3s grids are supported");
                chosen[i] = true;
            }
            if (!found)
                throw Error(label + ": no grid named " + dq(name) + "; the file holds: " +
                            list_grids(all));
        }
    } else {
        for (size_t i = 0; i < all.size(); ++i) {
            if (all[i]->isType<FloatGrid>() || all[i]->isType<openvdb::Vec3SGrid>())
                chosen[i] = true;
            else
                note("skipping grid " + grid_summary(*all[i]) +
                     ": only float and vec3s grids are converted");
        }
    }
    std::vector<Prepared> out;
    for (size_t i = 0; i < all.size(); ++i) {
        if (!chosen[i])
            continue;
        Prepared p;
        p.grid = openvdb::gridPtrCast<FloatGrid>(all[i]);
        p.vec = openvdb::gridPtrCast<openvdb::Vec3SGrid>(all[i]);
        p.name = p.base().getName();
        p.source_class = p.base().getGridClass();
        if (!p.base().transform().baseMap()->isLinear())
            throw Error(label + ": grid " + grid_summary(p.base()) + " has a non-affine (" +
                        p.base().transform().mapType() +
                        ") transform, which NanoVDB cannot represent");
        if (p.grid && p.source_class == openvdb::GRID_LEVEL_SET && !opts.keep_level_sets) {
            // Narrow band -> 0..1 ramp, interior 1 (active), exterior 0 (inactive)
            openvdb::tools::sdfToFogVolume(*p.grid);
            p.grid->setGridClass(openvdb::GRID_FOG_VOLUME);
            p.fogged = true;
        }
        out.push_back(std::move(p));
    }
    if (out.empty())
        throw Error(label + ": no float or vec3s grid to convert; the file holds: " + list_grids(all));
    return out;
}

// ---------------------------------------------------------------------------
//  Conversion
// ---------------------------------------------------------------------------

using Handle = nanovdb::GridHandle<nanovdb::HostBuffer>;

template <typename BuildT>
Handle convert_as(const FloatGrid &grid, const Options &opts) {
    nanovdb::OpenToNanoVDB<float, BuildT, nanovdb::AbsDiff> converter;
    if constexpr (std::is_same_v<BuildT, nanovdb::FpN>)
        if (opts.tolerance >= 0.f)
            converter.oracle().setTolerance(opts.tolerance);
    // Full checksum: the read-back check covers every byte of the grid
    return converter(grid, nanovdb::StatsMode::Default, nanovdb::ChecksumMode::Full, 0);
}

Handle convert_one(const FloatGrid &grid, Quantize q, const Options &opts) {
    try {
        switch (q) {
            case Quantize::Float: return convert_as<float>(grid, opts);
            case Quantize::Fp4: return convert_as<nanovdb::Fp4>(grid, opts);
            case Quantize::Fp8: return convert_as<nanovdb::Fp8>(grid, opts);
            case Quantize::Fp16: return convert_as<nanovdb::Fp16>(grid, opts);
            case Quantize::FpN: return convert_as<nanovdb::FpN>(grid, opts);
        }
    } catch (const std::exception &e) {
        throw Error("grid " + dq(grid.getName()) + ": NanoVDB conversion failed: " + e.what());
    }
    throw Error("unknown quantization");
}

/// A vec3s grid as NanoVDB's Vec3f (three floats per value, bit for bit)
Handle convert_vec3(const openvdb::Vec3SGrid &grid) {
    try {
        return nanovdb::openToNanoVDB<nanovdb::HostBuffer, openvdb::Vec3STree, nanovdb::Vec3f>(
            grid, nanovdb::StatsMode::Default, nanovdb::ChecksumMode::Full, 0);
    } catch (const std::exception &e) {
        throw Error("grid " + dq(grid.getName()) + ": NanoVDB conversion failed: " + e.what());
    }
}

/// NanoVDB 32.4's FpN encoder indexes its leaf array without checking that
/// there is one (OpenToNanoVDB::compression: mArray0[size-1]), so a grid
/// without leaf nodes is written as Fp16 instead: it has no quantized values.
Quantize effective_quantize(const FloatGrid &grid, Quantize q) {
    if (q == Quantize::FpN && grid.tree().leafCount() == 0)
        return Quantize::Fp16;
    return q;
}

/// Adds 1 to the first value of every leaf and recomputes the checksum: a
/// stand-in for a conversion bug, which only the value comparison can catch.
void corrupt_for_test(Handle &handle) {
    auto *grid = handle.grid<float>();
    if (!grid)
        throw Error("--corrupt-for-test works on float output only");
    auto *leaf = grid->tree().getFirstLeaf();
    for (uint32_t i = 0; i < grid->tree().nodeCount(0); ++i)
        leaf[i].data()->mValues[0] += 1.0f;
    nanovdb::updateChecksum(*grid, nanovdb::ChecksumMode::Full);
}

struct GridReport {
    std::string name, type, cls;
    uint64_t active = 0;
    CoordBBox bbox;                       // empty for an empty grid
    uint32_t nodes[3] = { 0, 0, 0 };      // leaf, lower, upper
    uint32_t tiles[3] = { 0, 0, 0 };      // active tiles: lower, upper, root
    uint64_t grid_bytes = 0, leaf_bytes = 0;
    double convert_ms = 0;
    std::string details; // grid_details(): world bbox, transform, value range
};

template <typename BuildT>
void fill_report(const nanovdb::NanoGrid<BuildT> &g, GridReport &r) {
    const auto &tree = g.tree();
    r.active = g.activeVoxelCount();
    const auto &b = g.indexBBox();
    if (!g.isEmpty() && b.min()[0] <= b.max()[0])
        r.bbox = CoordBBox(Coord(b.min()[0], b.min()[1], b.min()[2]),
                           Coord(b.max()[0], b.max()[1], b.max()[2]));
    for (int l = 0; l < 3; ++l) {
        r.nodes[l] = tree.nodeCount(l);
        r.tiles[l] = tree.data()->mTileCount[l];
    }
    r.grid_bytes = g.gridSize();
    if (r.nodes[0] > 0) {
        const uint8_t *base = reinterpret_cast<const uint8_t *>(&g);
        const uint8_t *first = reinterpret_cast<const uint8_t *>(tree.getFirstLeaf());
        uint64_t end = g.blindDataCount() > 0 ? uint64_t(g.data()->mBlindMetadataOffset)
                                              : g.gridSize();
        r.leaf_bytes = end - uint64_t(first - base);
    }
    r.type = nanovdb::toStr(g.gridType());
}

GridReport report_of(const Handle &h) {
    GridReport r;
    if (auto *g = h.grid<float>()) fill_report(*g, r);
    else if (auto *g = h.grid<nanovdb::Fp4>()) fill_report(*g, r);
    else if (auto *g = h.grid<nanovdb::Fp8>()) fill_report(*g, r);
    else if (auto *g = h.grid<nanovdb::Fp16>()) fill_report(*g, r);
    else if (auto *g = h.grid<nanovdb::FpN>()) fill_report(*g, r);
    else if (auto *g = h.grid<nanovdb::Vec3f>()) fill_report(*g, r);
    return r;
}

// ---------------------------------------------------------------------------
//  Verification: OpenVDB (after the fog conversion) vs the file read back
// ---------------------------------------------------------------------------

template <typename BuildT> constexpr Quantize quantize_of() {
    if constexpr (std::is_same_v<BuildT, nanovdb::Fp4>) return Quantize::Fp4;
    else if constexpr (std::is_same_v<BuildT, nanovdb::Fp8>) return Quantize::Fp8;
    else if constexpr (std::is_same_v<BuildT, nanovdb::Fp16>) return Quantize::Fp16;
    else if constexpr (std::is_same_v<BuildT, nanovdb::FpN>) return Quantize::FpN;
    else return Quantize::Float;
}

/// NanoVDB's default FpN tolerance (OpenToNanoVDB::compression), or the user's
float fpn_tolerance(const FloatGrid &g, const Options &opts) {
    if (opts.tolerance >= 0.f)
        return opts.tolerance;
    if (g.getGridClass() == openvdb::GRID_LEVEL_SET)
        return 0.1f * float(g.voxelSize()[0]);
    if (g.getGridClass() == openvdb::GRID_FOG_VOLUME)
        return 0.01f;
    return 0.f;
}

struct Verifier {
    const FloatGrid &vdb;
    const std::string &name;
    const Options &opts;
    uint64_t mismatches = 0;

    void fail(const std::string &msg) {
        ++mismatches;
        if (mismatches <= 10) {
            std::fflush(stdout);
            std::fprintf(stderr, "vdb2nvdb: verify: grid %s: %s\n", dq(name).c_str(), msg.c_str());
        }
    }

    template <typename BuildT>
    bool run(const nanovdb::NanoGrid<BuildT> &nano) {
        const Quantize q = quantize_of<BuildT>();
        std::string err = nanovdb::GridValidator<BuildT>::check(nano, /*detailed=*/true);
        if (!err.empty()) {
            fail("the written grid does not validate (NanoVDB GridValidator): " + err);
            return false;
        }
        // Whole-grid properties
        const std::string want_name = name.substr(0, nanovdb::GridData::MaxNameSize - 1);
        if (want_name != nano.shortGridName())
            fail("name " + dq(nano.shortGridName()) + " instead of " + dq(want_name));
        if (float_bits(nano.tree().background()) != float_bits(vdb.background()))
            fail("background " + fmt_float(nano.tree().background()) + " instead of " +
                 fmt_float(vdb.background()));
        if (nano.activeVoxelCount() != vdb.activeVoxelCount())
            fail("active voxel count " + fmt_count(nano.activeVoxelCount()) + " instead of " +
                 fmt_count(vdb.activeVoxelCount()));
        const CoordBBox vbox = vdb.evalActiveVoxelBoundingBox();
        const auto &nb = nano.indexBBox();
        const bool nano_empty = nano.isEmpty() || nb.min()[0] > nb.max()[0];
        if (vbox.empty() != nano_empty ||
            (!vbox.empty() && (Coord(nb.min()[0], nb.min()[1], nb.min()[2]) != vbox.min() ||
                               Coord(nb.max()[0], nb.max()[1], nb.max()[2]) != vbox.max())))
            fail("active index bbox differs from OpenVDB's " +
                 (vbox.empty() ? std::string("(empty)")
                               : "[" + fmt_coord(vbox.min()) + ", " + fmt_coord(vbox.max()) + "]"));
        const bool want_fog = vdb.getGridClass() == openvdb::GRID_FOG_VOLUME;
        const bool want_ls = vdb.getGridClass() == openvdb::GRID_LEVEL_SET;
        if ((want_fog && nano.gridClass() != nanovdb::GridClass::FogVolume) ||
            (want_ls && nano.gridClass() != nanovdb::GridClass::LevelSet))
            fail("grid class differs from OpenVDB's " + class_name(vdb.getGridClass()));
        {
            // index -> world at the corners of a box: the same affine map
            CoordBBox b = vbox.empty() ? CoordBBox(Coord(0), Coord(1)) : vbox;
            for (int c = 0; c < 8; ++c) {
                openvdb::Vec3d p((c & 1) ? b.max().x() : b.min().x(),
                                 (c & 2) ? b.max().y() : b.min().y(),
                                 (c & 4) ? b.max().z() : b.min().z());
                openvdb::Vec3d w = vdb.transform().indexToWorld(p);
                nanovdb::Vec3d n = nano.indexToWorld(nanovdb::Vec3d(p[0], p[1], p[2]));
                for (int k = 0; k < 3; ++k)
                    if (std::fabs(w[k] - n[k]) > 1e-9 * (1.0 + std::fabs(w[k]))) {
                        fail("index-to-world map differs at index " + fmt_coord(Coord(p[0], p[1], p[2])));
                        c = 8;
                        break;
                    }
            }
        }

        // Sample regions with active values: leaves and active tiles
        std::vector<const FloatGrid::TreeType::LeafNodeType *> leaves;
        leaves.reserve(vdb.tree().leafCount());
        for (auto it = vdb.tree().cbeginLeaf(); it; ++it)
            if (!it->isEmpty())
                leaves.push_back(it.getLeaf());
        std::vector<CoordBBox> tiles;
        {
            auto it = vdb.tree().cbeginValueOn();
            it.setMaxDepth(FloatGrid::TreeType::ValueOnCIter::LEAF_DEPTH - 1);
            for (; it; ++it)
                if (!it.isVoxelValue())
                    tiles.push_back(it.getBoundingBox());
        }
        const uint64_t regions = leaves.size() + tiles.size();

        const float tol = q == Quantize::FpN ? fpn_tolerance(vdb, opts) : 0.f;
        auto vacc = vdb.getConstAccessor();
        auto nacc = nano.getAccessor();
        // Largest error a quantized value may have: half a quantization step
        // of its leaf (NanoVDB rounds to the nearest code without dithering),
        // the FpN tolerance, and float rounding of code * quantum + minimum.
        auto bound = [&](const Coord &c) -> double {
            if (q == Quantize::Float)
                return 0.0;
            const auto *leaf = vacc.probeConstLeaf(c);
            if (!leaf)
                return 0.0; // tiles and the background are stored as floats
            float lo = std::numeric_limits<float>::max(), hi = -lo;
            for (openvdb::Index i = 0; i < 512; ++i) {
                lo = std::min(lo, leaf->getValue(i));
                hi = std::max(hi, leaf->getValue(i));
            }
            const double range = double(hi) - double(lo);
            const int bits = q == Quantize::Fp4 ? 4 : q == Quantize::Fp8 ? 8 : 16;
            double b = 0.5 * range / double((1u << bits) - 1);
            if (q == Quantize::FpN)
                b = std::max(double(tol), 0.5 * range / 65535.0);
            return b + 8.0 * FLT_EPSILON * (std::max(std::fabs(lo), std::fabs(hi)) + range);
        };

        Rng rng(opts.seed ^ 0x766462326e766462ull);
        const bool empty = vbox.empty();
        const CoordBBox inner = empty ? CoordBBox(Coord(-8), Coord(8)) : vbox;
        // The box grown by `m` voxels, clamped to int32 (no overflow at the extremes)
        auto grown = [&](int64_t m) {
            int64_t lo[3], hi[3];
            for (int k = 0; k < 3; ++k) {
                lo[k] = std::max<int64_t>(int64_t(inner.min()[k]) - m, INT32_MIN);
                hi[k] = std::min<int64_t>(int64_t(inner.max()[k]) + m, INT32_MAX);
            }
            return CoordBBox(Coord(int32_t(lo[0]), int32_t(lo[1]), int32_t(lo[2])),
                             Coord(int32_t(hi[0]), int32_t(hi[1]), int32_t(hi[2])));
        };
        const CoordBBox near = grown(2), outer = grown(64);
        uint64_t checked = 0;
        double worst = 0.0;
        for (uint64_t s = 0; s < opts.verify; ++s) {
            Coord c;
            const uint64_t kind = s % 3;
            if (kind == 0 && regions > 0) {
                // an active value: a random active voxel of a random leaf, or a tile
                const uint64_t r = rng.below(regions);
                if (r < leaves.size()) {
                    const auto *leaf = leaves[r];
                    const auto &mask = leaf->getValueMask();
                    openvdb::Index n = openvdb::Index(rng.below(512));
                    n = mask.findNextOn(n);
                    if (n >= 512)
                        n = mask.findFirstOn();
                    c = leaf->offsetToGlobalCoord(n);
                } else {
                    const CoordBBox &t = tiles[r - leaves.size()];
                    c = Coord(rng.range(t.min().x(), t.max().x()), rng.range(t.min().y(), t.max().y()),
                              rng.range(t.min().z(), t.max().z()));
                }
            } else if (kind != 2) {
                // anywhere in the active bbox (grown by 2 voxels)
                c = Coord(rng.range(near.min().x(), near.max().x()),
                          rng.range(near.min().y(), near.max().y()),
                          rng.range(near.min().z(), near.max().z()));
            } else if (rng.below(16) == 0) {
                // far away, up to the int32 extremes
                for (int k = 0; k < 3; ++k)
                    c[k] = int32_t(uint32_t(rng.next()));
            } else {
                // outside the active bbox, within 64 voxels of it (a few
                // tries: the box may fill the whole index space)
                for (int tries = 0; tries < 64; ++tries) {
                    c = Coord(rng.range(outer.min().x(), outer.max().x()),
                              rng.range(outer.min().y(), outer.max().y()),
                              rng.range(outer.min().z(), outer.max().z()));
                    if (empty || !inner.isInside(c))
                        break;
                }
            }
            const nanovdb::Coord nc(c.x(), c.y(), c.z());
            const float a = vacc.getValue(c), b = nacc.getValue(nc);
            const bool aon = vacc.isValueOn(c), bon = nacc.isActive(nc);
            bool same;
            double limit = 0.0;
            if (q == Quantize::Float) {
                same = float_bits(a) == float_bits(b);
            } else {
                limit = bound(c);
                const double d = std::fabs(double(a) - double(b));
                same = d <= limit || (std::isnan(a) && std::isnan(b));
                if (same)
                    worst = std::max(worst, d);
            }
            if (!same || aon != bon) {
                std::string msg = "mismatch at " + fmt_coord(c) + ": OpenVDB " + fmt_float(a) +
                                  (aon ? " (active)" : " (inactive)") + ", written file " +
                                  fmt_float(b) + (bon ? " (active)" : " (inactive)");
                if (q != Quantize::Float)
                    msg += ", allowed error " + fmt_float(limit);
                fail(msg);
            }
            ++checked;
        }
        if (mismatches > 10) {
            std::fflush(stdout);
            std::fprintf(stderr, "vdb2nvdb: verify: grid %s: %s mismatches in all\n",
                         dq(name).c_str(), fmt_count(mismatches).c_str());
        }
        if (mismatches == 0 && !opts.quiet) {
            std::string extra = q == Quantize::Float
                                    ? "identical"
                                    : "within the quantization bound (largest error " +
                                          fmt_float(worst) + ")";
            std::printf("verified %s: %s samples (active voxels, in and outside the bbox) %s\n",
                        dq(name).c_str(), fmt_count(checked).c_str(), extra.c_str());
        }
        return mismatches == 0;
    }
};

/// --verify for vec3s -> Vec3f: every sampled value bit for bit (3 floats)
/// and its active state, at random active voxels and points around the box
bool verify_vec3(const openvdb::Vec3SGrid &vdb, const nanovdb::NanoGrid<nanovdb::Vec3f> &nano,
                 const std::string &name, const Options &opts) {
    uint64_t mismatches = 0, checked = 0;
    auto fail = [&](const std::string &msg) {
        if (++mismatches <= 10) {
            std::fflush(stdout);
            std::fprintf(stderr, "vdb2nvdb: verify: grid %s: %s\n", dq(name).c_str(), msg.c_str());
        }
    };
    if (nano.activeVoxelCount() != vdb.activeVoxelCount())
        fail("active voxel count " + fmt_count(nano.activeVoxelCount()) + " instead of " +
             fmt_count(vdb.activeVoxelCount()));
    std::vector<const openvdb::Vec3STree::LeafNodeType *> leaves;
    for (auto it = vdb.tree().cbeginLeaf(); it; ++it)
        leaves.push_back(it.getLeaf());
    const CoordBBox vbox = vdb.evalActiveVoxelBoundingBox();
    auto vacc = vdb.getConstAccessor();
    auto nacc = nano.getAccessor();
    Rng rng(opts.seed ^ 0x766563337665633full);
    for (uint64_t s = 0; s < opts.verify; ++s) {
        Coord c;
        if (s % 2 == 0 && !leaves.empty()) {
            const auto *leaf = leaves[size_t(rng.below(leaves.size()))];
            c = leaf->offsetToGlobalCoord(openvdb::Index(rng.below(512)));
        } else {
            const CoordBBox b = vbox.empty() ? CoordBBox(Coord(-8), Coord(8))
                                             : CoordBBox(vbox.min().offsetBy(-2), vbox.max().offsetBy(2));
            c = Coord(rng.range(b.min().x(), b.max().x()), rng.range(b.min().y(), b.max().y()),
                      rng.range(b.min().z(), b.max().z()));
        }
        const openvdb::Vec3s a = vacc.getValue(c);
        const nanovdb::Vec3f v = nacc.getValue(nanovdb::Coord(c.x(), c.y(), c.z()));
        bool same = vacc.isValueOn(c) == nacc.isActive(nanovdb::Coord(c.x(), c.y(), c.z()));
        for (int k = 0; k < 3; ++k)
            same &= float_bits(a[k]) == float_bits(v[k]);
        if (!same)
            fail("mismatch at " + fmt_coord(c) + ": OpenVDB (" + fmt_float(a[0]) + ", " +
                 fmt_float(a[1]) + ", " + fmt_float(a[2]) + "), written file (" +
                 fmt_float(v[0]) + ", " + fmt_float(v[1]) + ", " + fmt_float(v[2]) + ")");
        ++checked;
    }
    if (mismatches == 0 && !opts.quiet)
        std::printf("verified %s: %s samples (voxels of its leaves, in and around the bbox) "
                    "identical\n", dq(name).c_str(), fmt_count(checked).c_str());
    return mismatches == 0;
}

// ---------------------------------------------------------------------------
//  Dense export (Mitsuba .vol, version 3)
// ---------------------------------------------------------------------------

struct DenseBox {
    Coord min{ 0 }, max{ 0 };
    uint64_t voxels() const {
        return uint64_t(max.x() - min.x() + 1) * uint64_t(max.y() - min.y() + 1) *
               uint64_t(max.z() - min.z() + 1);
    }
    int channels = 1;
    uint64_t bytes() const { return 48 + 4 * uint64_t(channels) * voxels(); }
};

/// The active index bbox [min, max], or the single voxel 0 for an empty grid
/// (which reads as its background, as nanovdbvolume does).
DenseBox dense_box(const CoordBBox &b) {
    DenseBox d;
    if (!b.empty()) {
        d.min = b.min();
        d.max = b.max();
    }
    return d;
}

uint64_t dense_limit(const Options &opts) {
    if (opts.max_dense_bytes)
        return opts.max_dense_bytes;
    uint64_t mem = physical_memory();
    return mem ? mem / 2 : (uint64_t(4) << 30);
}

template <typename BuildT>
void write_dense(const nanovdb::NanoGrid<BuildT> &nano, const openvdb::math::Transform &xform,
                 const DenseBox &box, const std::string &path) {
    const int32_t res[3] = { box.max.x() - box.min.x() + 1, box.max.y() - box.min.y() + 1,
                             box.max.z() - box.min.z() + 1 };
    // World-space extent of the voxels' cells: the index box [min - 0.5,
    // max + 0.5] through the grid transform (its axis-aligned bounds)
    openvdb::math::BBox<openvdb::Vec3d> wb;
    for (int c = 0; c < 8; ++c) {
        openvdb::Vec3d p((c & 1) ? box.max.x() + 0.5 : box.min.x() - 0.5,
                         (c & 2) ? box.max.y() + 0.5 : box.min.y() - 0.5,
                         (c & 4) ? box.max.z() + 0.5 : box.min.z() - 0.5);
        wb.expand(xform.indexToWorld(p));
    }
    std::ofstream os(path, std::ios::binary | std::ios::trunc);
    if (!os)
        throw Error("cannot write " + dq(path) + ": " + std::strerror(errno));
    using Value = typename nanovdb::NanoGrid<BuildT>::ValueType;
    constexpr int channels = std::is_same_v<Value, nanovdb::Vec3f> ? 3 : 1;
    const char magic[4] = { 'V', 'O', 'L', 3 };
    const int32_t header[5] = { 1, res[0], res[1], res[2], channels };
    const float bbox[6] = { float(wb.min()[0]), float(wb.min()[1]), float(wb.min()[2]),
                            float(wb.max()[0]), float(wb.max()[1]), float(wb.max()[2]) };
    os.write(magic, 4);
    os.write(reinterpret_cast<const char *>(header), sizeof(header));
    os.write(reinterpret_cast<const char *>(bbox), sizeof(bbox));
    // One z slab at a time: memory is one slab, not the dense grid
    std::vector<float> slab(size_t(res[0]) * size_t(res[1]) * channels);
    for (int32_t z = 0; z < res[2] && os; ++z) {
        tbb::parallel_for(tbb::blocked_range<int32_t>(0, res[1], 16),
                          [&](const tbb::blocked_range<int32_t> &r) {
            auto acc = nano.getAccessor();
            for (int32_t y = r.begin(); y != r.end(); ++y)
                for (int32_t x = 0; x < res[0]; ++x) {
                    const Value v = acc.getValue(
                        nanovdb::Coord(box.min.x() + x, box.min.y() + y, box.min.z() + z));
                    float *out = &slab[(size_t(y) * size_t(res[0]) + size_t(x)) * channels];
                    if constexpr (channels == 3) {
                        out[0] = v[0]; out[1] = v[1]; out[2] = v[2];
                    } else {
                        out[0] = v;
                    }
                }
        });
        os.write(reinterpret_cast<const char *>(slab.data()),
                 std::streamsize(slab.size() * sizeof(float)));
    }
    os.close();
    if (os.fail())
        throw Error("error writing " + dq(path) + " (disk full?)");
}

/// Calls f(grid) with the handle's typed grid.
template <typename F> void with_grid(const Handle &h, const std::string &name, F &&f) {
    if (auto *g = h.grid<float>()) f(*g);
    else if (auto *g = h.grid<nanovdb::Fp4>()) f(*g);
    else if (auto *g = h.grid<nanovdb::Fp8>()) f(*g);
    else if (auto *g = h.grid<nanovdb::Fp16>()) f(*g);
    else if (auto *g = h.grid<nanovdb::FpN>()) f(*g);
    else
        throw Error("grid " + dq(name) + " in the written file has type " +
                    std::string(nanovdb::toStr(h.gridType())) + ", expected a float grid");
}

void print_stats(const std::vector<GridReport> &reports, uint64_t file_size,
                 const std::string &out) {
    std::printf("\nstatistics of %s (%s, %zu grid%s)\n", out.c_str(), fmt_bytes(file_size).c_str(),
                reports.size(), reports.size() == 1 ? "" : "s");
    for (const GridReport &r : reports) {
        DenseBox d = dense_box(r.bbox);
        std::printf("  grid %s (%s, %s)\n", dq(r.name).c_str(), r.type.c_str(), r.cls.c_str());
        std::printf("    %-34s %s\n", "active voxels", fmt_count(r.active).c_str());
        if (r.bbox.empty())
            std::printf("    %-34s %s\n", "active index bbox", "(empty)");
        else
            std::printf("    %-34s [%s, %s]\n", "active index bbox", fmt_coord(r.bbox.min()).c_str(),
                        fmt_coord(r.bbox.max()).c_str());
        std::printf("    %-34s %d x %d x %d\n", "voxel dimensions", d.max.x() - d.min.x() + 1,
                    d.max.y() - d.min.y() + 1, d.max.z() - d.min.z() + 1);
        // world bbox, transform, value range: the lines of --list, aligned
        std::istringstream lines(r.details);
        for (std::string l; std::getline(lines, l);) {
            l.erase(0, l.find_first_not_of(' '));
            const size_t sp = l.find_first_of(" :");
            std::string key = l.substr(0, sp), rest = sp == std::string::npos ? "" : l.substr(sp);
            if (l.rfind("world bbox", 0) == 0) { key = "world bbox"; rest = l.substr(10); }
            else if (l.rfind("active values' largest channel", 0) == 0) {
                key = "active values' largest channel"; rest = l.substr(key.size());
            } else if (l.rfind("active values", 0) == 0) { key = "active values"; rest = l.substr(13); }
            rest.erase(0, rest.find_first_not_of(" :"));
            std::printf("    %-34s %s\n", key.c_str(), rest.c_str());
        }
        std::printf("    %-34s %s / %s / %s\n", "nodes upper / lower / leaf",
                    fmt_count(r.nodes[2]).c_str(), fmt_count(r.nodes[1]).c_str(),
                    fmt_count(r.nodes[0]).c_str());
        std::printf("    %-34s %s / %s / %s\n", "active tiles root/upper/lower",
                    fmt_count(r.tiles[2]).c_str(), fmt_count(r.tiles[1]).c_str(),
                    fmt_count(r.tiles[0]).c_str());
        std::printf("    %-34s %s\n", "grid size in memory", fmt_bytes(r.grid_bytes).c_str());
        std::printf("    %-34s %s (%.1f %% of the grid)\n", "leaf nodes", fmt_bytes(r.leaf_bytes).c_str(),
                    r.grid_bytes ? 100.0 * double(r.leaf_bytes) / double(r.grid_bytes) : 0.0);
        std::printf("    %-34s %s\n", "dense equivalent (voxels x 4 B)", fmt_bytes(4 * d.voxels()).c_str());
        std::printf("    %-34s %.4f\n", "grid size / dense size",
                    double(r.grid_bytes) / double(4 * d.voxels()));
        std::printf("    %-34s %.1f ms\n", "conversion time", r.convert_ms);
    }
    std::printf("  %-36s %s\n", ".nvdb file size", fmt_bytes(file_size).c_str());
}

void print_probes(const FloatGrid &vdb, const Handle &h, const std::string &name,
                  const Options &opts) {
    auto vacc = vdb.getConstAccessor();
    with_grid(h, name, [&](const auto &nano) {
        auto nacc = nano.getAccessor();
        for (const Coord &c : opts.probes) {
            const nanovdb::Coord nc(c.x(), c.y(), c.z());
            std::printf("probe %s %d,%d,%d openvdb %s %s nanovdb %s %s\n", dq(name).c_str(),
                        c.x(), c.y(), c.z(), fmt_float(vacc.getValue(c)).c_str(),
                        vacc.isValueOn(c) ? "on" : "off", fmt_float(nacc.getValue(nc)).c_str(),
                        nacc.isActive(nc) ? "on" : "off");
        }
    });
}

} // namespace

// ---------------------------------------------------------------------------
//  The pipeline
// ---------------------------------------------------------------------------

int convert_grids(openvdb::GridPtrVec all, const std::string &label, const std::string &out,
                  const Options &opts) {
    // Create the output first: an unwritable path fails before any work
    TempFile out_tmp(out);
    std::vector<Prepared> grids = select_and_prepare(all, label, opts);

    // Dense exports: sizes checked before anything is converted
    std::vector<std::unique_ptr<TempFile>> dense_tmps;
    std::vector<DenseBox> dense_boxes;
    if (!opts.dense.empty()) {
        const uint64_t limit = dense_limit(opts);
        for (size_t i = 0; i < grids.size(); ++i) {
            DenseBox d = dense_box(grids[i].base().evalActiveVoxelBoundingBox());
            d.channels = grids[i].vec ? 3 : 1;
            if (d.bytes() > limit)
                throw Error("--dense: grid " + dq(grids[i].name) + " would need " +
                            fmt_bytes(d.bytes()) + " dense (" + fmt_count(d.voxels()) +
                            " voxels), more than the limit of " + fmt_bytes(limit) +
                            (opts.max_dense_bytes ? " (--max-dense-bytes)"
                                                  : " (half the physical memory; raise it with "
                                                    "--max-dense-bytes)"));
            dense_boxes.push_back(d);
        }
        std::set<std::string> used;
        for (size_t i = 0; i < grids.size(); ++i) {
            std::string path = opts.dense;
            if (grids.size() > 1) {
                // OUT.vol -> OUT_<grid>.vol, one file per grid (OUT_<grid>_<index>.vol
                // for a repeated name)
                fs::path p(opts.dense);
                std::string stem = p.stem().string(), ext = p.extension().string();
                if (ext.empty())
                    ext = ".vol";
                std::string tag = safe_name(grids[i].name, i);
                if (!used.insert(tag).second)
                    tag += "_" + std::to_string(i);
                path = (p.parent_path() / (stem + "_" + tag + ext)).string();
            }
            dense_tmps.push_back(std::make_unique<TempFile>(path));
        }
    }

    // Convert and write, one grid (one segment) at a time
    std::vector<GridReport> reports;
    {
        std::ofstream os(out_tmp.tmp_path(), std::ios::binary | std::ios::trunc);
        if (!os)
            throw Error("cannot write " + dq(out) + ": " + std::strerror(errno));
        for (Prepared &p : grids) {
            auto t0 = Clock::now();
            Handle h;
            if (p.vec) {
                if (opts.quantize != Quantize::Float)
                    note("grid " + dq(p.name) + " (vec3s) is written as Vec3f: --quantize "
                         "applies to float grids");
                h = convert_vec3(*p.vec);
            } else {
                const Quantize q = effective_quantize(*p.grid, opts.quantize);
                if (q != opts.quantize)
                    note("grid " + dq(p.name) + " has no leaf nodes: written as fp16 instead of "
                         "fpn (NanoVDB 32.4's FpN encoder needs a leaf); it holds no quantized "
                         "values");
                h = convert_one(*p.grid, q, opts);
                if (opts.corrupt_for_test)
                    corrupt_for_test(h);
            }
            GridReport r = report_of(h);
            r.name = p.name;
            if (opts.stats) // as written: after a level set's fog conversion
                r.details = grid_details(p.base(), p.base().evalActiveVoxelBoundingBox());
            r.cls = class_name(p.base().getGridClass());
            try {
                nanovdb::io::writeGrid(os, h, opts.codec);
            } catch (const std::exception &e) {
                throw Error("cannot write " + dq(out) + ": " + e.what());
            }
            if (!os)
                throw Error("error writing " + dq(out) + " (disk full?)");
            r.convert_ms = ms_since(t0);
            say(opts, "converted " + dq(p.name) +
                          (p.fogged ? " (level set -> fog volume)" : "") + ": " +
                          fmt_count(r.active) + " active voxels, " + r.type + ", " +
                          fmt_bytes(r.grid_bytes) + ", " + fmt_float(std::round(r.convert_ms)) + " ms");
            reports.push_back(std::move(r));
        }
        os.close();
        if (os.fail())
            throw Error("error writing " + dq(out) + " (disk full?)");
    }
    const uint64_t file_size = fs::file_size(out_tmp.tmp_path());

    // Read the file back from disk with NanoVDB's reader: verify, dense, probes
    bool ok = true;
    if (opts.verify > 0 || !opts.dense.empty() || !opts.probes.empty()) {
        for (size_t i = 0; i < grids.size(); ++i) {
            Handle h;
            try {
                h = nanovdb::io::readGrid<nanovdb::HostBuffer>(out_tmp.tmp_path(), uint64_t(i));
            } catch (const std::exception &e) {
                throw Error("cannot read back the written file " + dq(out) + ": " + e.what(),
                            ExitVerify);
            }
            auto t0 = Clock::now();
            auto check_and_export = [&](const auto &nano, auto &&verify) {
                if (opts.verify > 0)
                    ok = verify(nano) && ok;
                if (ok && !opts.dense.empty()) {
                    write_dense(nano, grids[i].base().transform(), dense_boxes[i],
                                dense_tmps[i]->tmp_path());
                    say(opts, "dense export of " + dq(grids[i].name) + ": " +
                                  dense_tmps[i]->path());
                }
            };
            if (grids[i].vec) {
                const auto *nano = h.grid<nanovdb::Vec3f>();
                if (!nano)
                    throw Error("grid " + dq(grids[i].name) + " in the written file is not Vec3f",
                                ExitVerify);
                check_and_export(*nano, [&](const auto &n) {
                    return verify_vec3(*grids[i].vec, n, grids[i].name, opts);
                });
                continue; // probes: float grids
            }
            with_grid(h, grids[i].name, [&](const auto &nano) {
                check_and_export(nano, [&](const auto &n) {
                    Verifier v{ *grids[i].grid, grids[i].name, opts };
                    return v.run(n);
                });
            });
            if (ok && !opts.probes.empty())
                print_probes(*grids[i].grid, h, grids[i].name, opts);
            (void) t0;
        }
    }
    if (!ok) {
        std::fflush(stdout);
        std::fprintf(stderr, "vdb2nvdb: error: verification failed; %s was not written\n",
                     out.c_str());
        return ExitVerify;
    }
    out_tmp.commit();
    for (auto &t : dense_tmps)
        t->commit();
    say(opts, "wrote " + out + " (" + fmt_bytes(file_size) + ", " + std::to_string(grids.size()) +
                  " grid" + (grids.size() == 1 ? "" : "s") + ", " + quantize_name(opts.quantize) +
                  ")");
    if (opts.stats)
        print_stats(reports, file_size, out);
    return ExitOk;
}

int convert_file(const std::string &in, const std::string &out, const Options &opts) {
    // Fail on an unwritable output before reading a large input
    { TempFile probe(out); }
    return convert_grids(read_input(in), dq(in), out, opts);
}

int verify_only(const std::string &in, const std::string &nvdb, const Options &opts) {
    openvdb::GridPtrVec all = read_input(in);
    std::vector<Prepared> grids = select_and_prepare(all, dq(in), opts);
    std::vector<nanovdb::io::GridMetaData> meta;
    try {
        meta = nanovdb::io::readGridMetaData(nvdb);
    } catch (const std::exception &e) {
        throw Error(dq(nvdb) + ": cannot read as a NanoVDB file: " + e.what(), ExitVerify);
    }
    if (meta.size() != grids.size())
        throw Error(dq(nvdb) + " holds " + std::to_string(meta.size()) + " grid(s), but " +
                        std::to_string(grids.size()) + " would be converted from " + dq(in),
                    ExitVerify);
    Options o = opts;
    if (o.verify == 0)
        o.verify = 100000;
    bool ok = true;
    for (size_t i = 0; i < grids.size(); ++i) {
        Handle h;
        try {
            h = nanovdb::io::readGrid<nanovdb::HostBuffer>(nvdb, uint64_t(i));
        } catch (const std::exception &e) {
            throw Error(dq(nvdb) + ": cannot read grid " + std::to_string(i) + ": " + e.what(),
                        ExitVerify);
        }
        if (grids[i].vec) {
            const auto *nano = h.grid<nanovdb::Vec3f>();
            ok = nano && verify_vec3(*grids[i].vec, *nano, grids[i].name, o) && ok;
            continue;
        }
        with_grid(h, grids[i].name, [&](const auto &nano) {
            Verifier v{ *grids[i].grid, grids[i].name, o };
            ok = v.run(nano) && ok;
        });
        if (!opts.probes.empty())
            print_probes(*grids[i].grid, h, grids[i].name, opts);
    }
    if (!ok) {
        std::fflush(stdout);
        std::fprintf(stderr, "vdb2nvdb: error: %s does not match %s\n", nvdb.c_str(), in.c_str());
        return ExitVerify;
    }
    say(opts, nvdb + " matches " + in);
    return ExitOk;
}

} // namespace vdb2nvdb
