// nvdb_make_stability_grid: grids for tests/test_stability.py (stiff and
// extreme cases), built with OpenVDB and converted by NanoVDB's own
// openToNanoVDB, written by NanoVDB's writer; optionally the dense export of
// the active box as a Mitsuba .vol (nvdb_test::write_dense_vol).
//
//   nvdb_make_stability_grid OUT.nvdb [options]
//     --min I J K --max I J K   inclusive index box (default 0..7)
//     --fill constant|random|ramp|columns|none   (default constant)
//         constant: --value V everywhere in the box
//         random:   log-uniform in [--lo, --hi] (seeded by --seed)
//         ramp:     value = i - min_i (a linear ramp along x)
//         columns:  value = lo * ratio^(i - min_i) (one value per x column)
//         none:     no voxels (an empty grid)
//     --tiles                   constant fill with the largest tiles OpenVDB
//                               can use (tree.fill); otherwise voxels
//     --background B            (default 0)
//     --voxel SX SY SZ          voxel size, may be non-uniform (default 1)
//     --translate X Y Z         world position of voxel (0, 0, 0) (default 0)
//     --set I J K V             one voxel value (nan, inf, -inf allowed), repeatable
//     --tile LEVEL I J K V      a tile at level 1/2/3 holding (I, J K), repeatable
//     --dense OUT.vol           dense export of the active box
//     --codec none|zip|blosc
// Prints one line: bbox, bytes.

#include "grids.h"
#include "testdata/seeded.h"

#include <nanovdb/util/IO.h>
#include <nanovdb/util/OpenToNanoVDB.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

float parse_float(const std::string &s) {
    char *end = nullptr;
    const float v = std::strtof(s.c_str(), &end); // accepts nan, inf, -inf
    if (s.empty() || *end != '\0') throw std::invalid_argument("not a number: \"" + s + "\"");
    return v;
}

int32_t parse_int(const std::string &s) {
    char *end = nullptr;
    const long long v = std::strtoll(s.c_str(), &end, 10);
    if (s.empty() || *end != '\0' || v < INT32_MIN || v > INT32_MAX)
        throw std::invalid_argument("not an int32: \"" + s + "\"");
    return int32_t(v);
}

struct Tile { int level; openvdb::Coord ijk; float value; };

} // namespace

int main(int argc, char **argv) {
    try {
        std::string out, dense, fill = "constant", codec_name = "none";
        openvdb::Coord lo(0, 0, 0), hi(7, 7, 7);
        float value = 1.f, vlo = 1e-6f, vhi = 1e6f, ratio = 10.f, background = 0.f;
        double voxel[3] = { 1, 1, 1 }, translate[3] = { 0, 0, 0 };
        bool tiles = false;
        uint64_t seed = 1;
        std::vector<std::pair<openvdb::Coord, float>> sets;
        std::vector<Tile> extra_tiles;
        auto need = [&](int i, int n) {
            if (i + n >= argc) throw std::invalid_argument(std::string(argv[i]) + " needs " +
                                                           std::to_string(n) + " values");
        };
        for (int i = 1; i < argc; ++i) {
            const std::string a = argv[i];
            if (a == "--min" || a == "--max") {
                need(i, 3);
                openvdb::Coord c(parse_int(argv[i + 1]), parse_int(argv[i + 2]), parse_int(argv[i + 3]));
                (a == "--min" ? lo : hi) = c;
                i += 3;
            } else if (a == "--fill") { need(i, 1); fill = argv[++i]; }
            else if (a == "--value") { need(i, 1); value = parse_float(argv[++i]); }
            else if (a == "--lo") { need(i, 1); vlo = parse_float(argv[++i]); }
            else if (a == "--hi") { need(i, 1); vhi = parse_float(argv[++i]); }
            else if (a == "--ratio") { need(i, 1); ratio = parse_float(argv[++i]); }
            else if (a == "--background") { need(i, 1); background = parse_float(argv[++i]); }
            else if (a == "--seed") { need(i, 1); seed = std::strtoull(argv[++i], nullptr, 10); }
            else if (a == "--tiles") tiles = true;
            else if (a == "--voxel" || a == "--translate") {
                need(i, 3);
                double *d = a == "--voxel" ? voxel : translate;
                for (int k = 0; k < 3; ++k) d[k] = std::strtod(argv[i + 1 + k], nullptr);
                i += 3;
            } else if (a == "--set") {
                need(i, 4);
                sets.push_back({ openvdb::Coord(parse_int(argv[i + 1]), parse_int(argv[i + 2]),
                                                parse_int(argv[i + 3])),
                                 parse_float(argv[i + 4]) });
                i += 4;
            } else if (a == "--tile") {
                need(i, 5);
                extra_tiles.push_back({ parse_int(argv[i + 1]),
                                        openvdb::Coord(parse_int(argv[i + 2]), parse_int(argv[i + 3]),
                                                       parse_int(argv[i + 4])),
                                        parse_float(argv[i + 5]) });
                i += 5;
            } else if (a == "--dense") { need(i, 1); dense = argv[++i]; }
            else if (a == "--codec") { need(i, 1); codec_name = argv[++i]; }
            else if (!a.empty() && a[0] == '-') throw std::invalid_argument("unknown option " + a);
            else if (out.empty()) out = a;
            else throw std::invalid_argument("unexpected argument " + a);
        }
        if (out.empty()) throw std::invalid_argument("OUT.nvdb is required");

        openvdb::initialize();
        auto grid = openvdb::FloatGrid::create(background);
        grid->setName("stability");
        grid->setGridClass(openvdb::GRID_FOG_VOLUME);
        auto &tree = grid->tree();
        const openvdb::CoordBBox box(lo, hi);
        if (fill == "constant") {
            if (tiles) tree.fill(box, value, true);
            else tree.denseFill(box, value, true);
        } else if (fill == "random" || fill == "ramp" || fill == "columns") {
            auto acc = grid->getAccessor();
            const double llo = std::log(double(vlo)), lhi = std::log(double(vhi));
            for (int64_t i = lo[0]; i <= hi[0]; ++i)
                for (int64_t j = lo[1]; j <= hi[1]; ++j)
                    for (int64_t k = lo[2]; k <= hi[2]; ++k) {
                        float v;
                        if (fill == "random") {
                            using nvdb_testdata::splitmix64;
                            const uint64_t h = splitmix64(seed ^ splitmix64(uint64_t(i) ^
                                                splitmix64(uint64_t(j) ^ splitmix64(uint64_t(k)))));
                            const double u = nvdb_testdata::unit_interval(h);
                            v = float(std::exp(llo + u * (lhi - llo)));
                        } else if (fill == "ramp") {
                            v = float(i - lo[0]);
                        } else {
                            v = float(double(vlo) * std::pow(double(ratio), double(i - lo[0])));
                        }
                        acc.setValueOn(openvdb::Coord(int32_t(i), int32_t(j), int32_t(k)), v);
                    }
        } else if (fill != "none") {
            throw std::invalid_argument("unknown --fill " + fill);
        }
        for (const Tile &t : extra_tiles) tree.addTile(t.level, t.ijk, t.value, true);
        for (const auto &s : sets) tree.setValueOn(s.first, s.second);

        // BBox: the index bbox the plugin spans (no min/max statistics: the
        // plugin computes its own bound; NaN voxels would poison them)
        auto handle = nanovdb::openToNanoVDB(*grid, nanovdb::StatsMode::BBox);
        const auto *g = handle.grid<float>();
        if (!g) throw std::runtime_error("openToNanoVDB did not produce a float grid");
        // The index -> world map (scale, then translation), set on the
        // NanoVDB grid directly: OpenVDB refuses affine maps whose
        // determinant is below ~1e-15 (voxels of 1e-6), which NanoVDB stores
        // fine. Row-vector convention of OpenVDB/NanoVDB: translation in row 3.
        {
            openvdb::math::Mat4d m = openvdb::math::Mat4d::identity(), inv = m;
            for (int k = 0; k < 3; ++k) {
                m[k][k] = voxel[k];
                m[3][k] = translate[k];
                inv[k][k] = 1.0 / voxel[k];
                inv[3][k] = -translate[k] / voxel[k];
            }
            auto *data = reinterpret_cast<nanovdb::GridData *>(handle.data());
            data->mMap.set(m, inv, 1.0);
            data->mVoxelSize = nanovdb::Vec3R(voxel[0], voxel[1], voxel[2]);
            const auto ib = g->indexBBox();
            nanovdb::Vec3R wmin, wmax;
            for (int k = 0; k < 3; ++k) {
                wmin[k] = translate[k] + voxel[k] * (double(ib.min()[k]) - 0.5);
                wmax[k] = translate[k] + voxel[k] * (double(ib.max()[k]) + 0.5);
            }
            data->mWorldBBox = nanovdb::BBox<nanovdb::Vec3R>(wmin, wmax);
        }
        nanovdb::io::Codec codec = codec_name == "zip" ? nanovdb::io::Codec::ZIP
                                 : codec_name == "blosc" ? nanovdb::io::Codec::BLOSC
                                 : nanovdb::io::Codec::NONE;
        nanovdb::io::writeGrid(out, handle, codec);
        if (!dense.empty()) nvdb_test::write_dense_vol(*g, dense);
        const auto b = g->indexBBox();
        std::printf("bbox %d %d %d %d %d %d bytes %llu leaves %u lowers %u uppers %u\n",
                    b.min()[0], b.min()[1], b.min()[2], b.max()[0], b.max()[1], b.max()[2],
                    (unsigned long long) handle.size(), g->tree().nodeCount(0),
                    g->tree().nodeCount(1), g->tree().nodeCount(2));
    } catch (const std::exception &e) {
        std::cerr << "nvdb_make_stability_grid: " << e.what() << "\n";
        return 1;
    }
    return 0;
}
