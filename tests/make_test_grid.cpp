// nvdb_make_test_grid: writes a named test grid (tests/grids.h) as .nvdb through
// NanoVDB's own writer, and optionally its dense export as a Mitsuba .vol.
// Used by the pytest suite.
//
//   nvdb_make_test_grid NAME OUT.nvdb [--dense OUT.vol] [--codec none|zip|blosc]
//                       [--scale N] [--type float|fp4|fp8|fp16|fpn|half|vec3f]
//                       [--root-key-bit 20|41|62|63]
//
// --type: the grid in another value type (tests/typed_grids.h); --dense then
// exports its decoded values (NanoVDB's accessor; Half: F16C). Half grids are
// written as a raw grid buffer (NanoVDB 32.4's writer cannot build them).
// --root-key-bit: a hostile file (a fuzzer seed, float grids): that bit set
// in the first root tile's key, one that no coordinate has (the loader must
// refuse it: an index by block would find the tile, PNanoVDB never does).
//   nvdb_make_test_grid --list
//
// Prints one summary line per grid; exits 2 on bad arguments, 1 on failure.

#include "grids.h"
#include "typed_grids.h"

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <iostream>
#include <string>

#include <nanovdb/util/IO.h>

namespace {

const char *usage =
    "usage: nvdb_make_test_grid NAME OUT.nvdb [--dense OUT.vol] [--codec none|zip|blosc] "
    "[--scale N] [--type float|fp4|fp8|fp16|fpn|half|vec3f] [--root-key-bit 20|41|62|63]\n"
    "       nvdb_make_test_grid --list\n";

int bad_args(const std::string &message) {
    std::cerr << "nvdb_make_test_grid: " << message << "\n" << usage;
    return 2;
}

std::string valid_names() {
    std::string out;
    for (const std::string &n : nvdb_test::grid_names())
        out += (out.empty() ? "" : ", ") + n;
    return out;
}

} // namespace

int main(int argc, char **argv) {
    std::string name, out_path, dense_path, codec_name = "none", type = "float";
    int scale = 1, key_bit = -1;
    bool have_name = false, have_out = false;

    for (int i = 1; i < argc; ++i) {
        const std::string arg = argv[i];
        auto value = [&](std::string &dst) {
            if (i + 1 >= argc)
                return false;
            dst = argv[++i];
            return true;
        };
        if (arg == "--list") {
            for (const std::string &n : nvdb_test::grid_names())
                std::cout << n << "\n";
            return 0;
        } else if (arg == "-h" || arg == "--help") {
            std::cout << usage << "grids: " << valid_names() << "\n";
            return 0;
        } else if (arg == "--dense") {
            if (!value(dense_path))
                return bad_args("--dense needs a file name");
        } else if (arg == "--type") {
            if (!value(type))
                return bad_args("--type needs one of float, fp4, fp8, fp16, fpn, half, vec3f");
            try {
                nvdb_test::grid_type_of(type);
            } catch (const std::exception &e) {
                return bad_args(e.what());
            }
        } else if (arg == "--codec") {
            if (!value(codec_name))
                return bad_args("--codec needs one of none, zip, blosc");
        } else if (arg == "--scale") {
            std::string s;
            if (!value(s))
                return bad_args("--scale needs an integer >= 1");
            char *end = nullptr;
            const long v = std::strtol(s.c_str(), &end, 10);
            if (s.empty() || *end != '\0' || v < 1 || v > 64)
                return bad_args("--scale must be an integer in [1, 64], got \"" + s + "\"");
            scale = int(v);
        } else if (arg == "--root-key-bit") {
            std::string s;
            if (!value(s) || (s != "20" && s != "41" && s != "62" && s != "63"))
                return bad_args("--root-key-bit needs 20, 41, 62 or 63 (the bits no key of a "
                                "coordinate has)");
            key_bit = std::stoi(s);
        } else if (arg.size() > 1 && arg[0] == '-') {
            return bad_args("unknown option \"" + arg + "\"");
        } else if (!have_name) {
            name = arg;
            have_name = true;
        } else if (!have_out) {
            out_path = arg;
            have_out = true;
        } else {
            return bad_args("unexpected argument \"" + arg + "\"");
        }
    }
    if (!have_name || !have_out)
        return bad_args("NAME and OUT.nvdb are required");

    nanovdb::io::Codec codec;
    if (codec_name == "none")
        codec = nanovdb::io::Codec::NONE;
    else if (codec_name == "zip")
        codec = nanovdb::io::Codec::ZIP;
    else if (codec_name == "blosc")
        codec = nanovdb::io::Codec::BLOSC;
    else
        return bad_args("unknown codec \"" + codec_name + "\"; valid codecs: none, zip, blosc");

    if (key_bit >= 0 && type != "float")
        return bad_args("--root-key-bit is for float grids");

    bool known = false;
    for (const std::string &n : nvdb_test::grid_names())
        known |= n == name;
    if (!known)
        return bad_args("unknown grid \"" + name + "\"; valid names: " + valid_names());

    try {
        const auto t0 = std::chrono::steady_clock::now();
        nvdb_test::TypedGrid typed = nvdb_test::make_typed_grid(name, type, scale);
        const auto t1 = std::chrono::steady_clock::now();
        const nanovdb::NanoGrid<float> *grid = typed.float_grid.grid<float>();
        if (!grid)
            throw std::runtime_error("openToNanoVDB did not produce a float grid");

        // Refuse an impossible dense export before writing anything.
        if (!dense_path.empty() &&
            nvdb_test::dense_voxel_count(*grid) > nvdb_test::max_dense_voxels)
            throw std::length_error(
                "the dense export would hold " +
                std::to_string(nvdb_test::dense_voxel_count(*grid)) +
                " voxels (limit " + std::to_string(nvdb_test::max_dense_voxels) +
                "); nothing written");

        if (key_bit >= 0) {
            auto &root = typed.handle.grid<float>()->tree().root();
            if (root.tileCount() == 0)
                throw std::invalid_argument("--root-key-bit: the grid has no root tile");
            root.data()->tile(0)->key |= uint64_t(1) << key_bit;
        }
        if (type == "half") {
            if (codec != nanovdb::io::Codec::NONE)
                throw std::invalid_argument("half grids are written raw, without a codec");
            std::ofstream f(out_path, std::ios::binary);
            f.write(reinterpret_cast<const char *>(typed.words.data()), std::streamsize(typed.bytes));
            if (!f.flush())
                throw std::runtime_error("cannot write \"" + out_path + "\"");
        } else {
            nanovdb::io::writeGrid(out_path, typed.handle, codec);
        }
        if (!dense_path.empty() && type == "vec3f")
            nvdb_test::write_dense_vol(*grid, dense_path, 3, typed.reference3());
        else if (!dense_path.empty())
            nvdb_test::write_dense_vol(*grid, dense_path,
                                       type == "float" ? nullptr : typed.reference());
        const auto t2 = std::chrono::steady_clock::now();

        const nanovdb::CoordBBox bbox = grid->indexBBox();
        auto ms = [](auto a, auto b) {
            return std::chrono::duration<double, std::milli>(b - a).count();
        };
        std::printf("%s (%s): bbox [%d, %d, %d] .. [%d, %d, %d], %llu active voxels, "
                    "%llu bytes in memory, %llu bytes in %s (codec %s%s%s), "
                    "built in %.1f ms, written in %.1f ms\n",
                    name.c_str(), type.c_str(), bbox.min()[0], bbox.min()[1], bbox.min()[2], bbox.max()[0],
                    bbox.max()[1], bbox.max()[2],
                    (unsigned long long) grid->activeVoxelCount(),
                    (unsigned long long) typed.bytes,
                    (unsigned long long) std::filesystem::file_size(out_path), out_path.c_str(),
                    codec_name.c_str(), dense_path.empty() ? "" : ", dense ",
                    dense_path.c_str(), ms(t0, t1), ms(t1, t2));
    } catch (const std::exception &e) {
        std::cerr << "nvdb_make_test_grid: " << name << ": " << e.what() << "\n";
        return 1;
    }
    return 0;
}
