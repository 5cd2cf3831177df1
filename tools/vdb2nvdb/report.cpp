// What was written, grid by grid. See report.h.

#include "report.h"

#include <cstdio>
#include <sstream>

#include <nanovdb_convert/format.h>
#include "dense.h"

namespace vdb2nvdb {

using openvdb::Coord;
using openvdb::CoordBBox;

namespace {

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

} // namespace

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

} // namespace vdb2nvdb
