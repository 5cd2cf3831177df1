// vdb2nvdb --list. See describe.h.

#include "describe.h"

#include <algorithm>
#include <cctype>
#include <cstdio>

#include <nanovdb_convert/error.h>
#include <nanovdb_convert/format.h>
#include "read.h"

namespace vdb2nvdb {

using openvdb::Coord;
using openvdb::CoordBBox;
using openvdb::FloatGrid;

namespace {

/// "[(x, y, z), (x, y, z)]" of a world-space box
std::string fmt_world_box(const openvdb::math::BBox<openvdb::Vec3d> &b) {
    char s[200];
    std::snprintf(s, sizeof(s), "[(%g, %g, %g), (%g, %g, %g)]", b.min()[0], b.min()[1], b.min()[2],
                  b.max()[0], b.max()[1], b.max()[2]);
    return s;
}

std::string lower(std::string s) {
    for (char &c : s)
        c = char(std::tolower((unsigned char) c));
    return s;
}

} // namespace

std::vector<std::string>
render_roles(const std::vector<std::pair<std::string, std::string>> &grids) {
    // As python/nanovdb_mitsuba/fire.py (default_density, emission_candidates,
    // default_mode): keep the two in step
    static const char *kEmission[] = {"emission", "flame", "temperature", "heat"};
    std::vector<std::string> roles(grids.size());
    size_t density = grids.size();
    for (size_t i = 0; i < grids.size() && density == grids.size(); ++i)
        if (grids[i].second == "float" && lower(grids[i].first) == "density")
            density = i;
    for (size_t i = 0; i < grids.size() && density == grids.size(); ++i)
        if (grids[i].second == "float")
            density = i;
    if (density < grids.size())
        roles[density] = "density";
    bool chosen = false;
    for (const char *name : kEmission)
        for (size_t i = 0; i < grids.size(); ++i) {
            if (i == density || lower(grids[i].first) != name)
                continue;
            if (chosen) {
                roles[i] = "emission-like, unused";
                continue;
            }
            const std::string n(name);
            const bool temperature =
                (n == "temperature" || n == "heat") && grids[i].second == "float";
            roles[i] = temperature ? "emission (temperature)" : "emission (radiance)";
            chosen = true;
        }
    return roles;
}

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
    std::printf("  %-3s %-20s %-12s %-11s %15s  %-44s %-30s  %s\n", "#", "name", "type",
                "class", "active voxels", "active index bbox [min, max]", "voxel size",
                "nanovdb-render");
    std::vector<std::pair<std::string, std::string>> names;
    for (const auto &g : grids)
        names.emplace_back(g->getName(), g->valueType());
    const std::vector<std::string> roles = render_roles(names);
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
        char row[512];
        std::snprintf(row, sizeof(row), "  %-3zu %-20s %-12s %-11s %15s  %-44s %-30s  %s", i,
                      dq(g.getName()).c_str(), g.valueType().c_str(),
                      class_name(g.getGridClass()).c_str(),
                      fmt_count(g.activeVoxelCount()).c_str(), bbox.c_str(), vsz,
                      roles[i].c_str());
        std::string line(row);
        line.erase(line.find_last_not_of(' ') + 1);
        std::printf("%s\n", line.c_str());
        std::printf("%s", grid_details(g, box).c_str());
    }
    return ExitOk;
}

} // namespace vdb2nvdb
