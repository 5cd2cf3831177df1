// vdb2nvdb generate: a synthetic test volume (tools/testdata/generate_cases.h)
// written as .vdb and, optionally, converted to .nvdb. See generate.h.

#include "generate.h"

#include <chrono>
#include <cstdio>
#include <stdexcept>

#include "testdata/generate_cases.h"
#include "temp_file.h"

namespace vdb2nvdb {

int generate(const std::string &name, const std::string &out_vdb, const std::string &out_nvdb,
             const Options &opts) {
    TempFile vdb_tmp(out_vdb);
    if (!out_nvdb.empty()) { TempFile probe(out_nvdb); }
    auto t0 = std::chrono::steady_clock::now();
    openvdb::GridPtrVec grids;
    try {
        grids = nvdb_testdata::make_case(name);
    } catch (const std::invalid_argument &e) {
        throw Error(e.what(), ExitUsage);
    }
    auto t1 = std::chrono::steady_clock::now();
    try {
        openvdb::io::File file(vdb_tmp.tmp_path());
        // Blosc (fast) when OpenVDB has it, zip otherwise; active-mask compression
        uint32_t compression = openvdb::io::COMPRESS_ACTIVE_MASK |
                               (openvdb::io::Archive::hasBloscCompression()
                                    ? openvdb::io::COMPRESS_BLOSC
                                    : openvdb::io::COMPRESS_ZIP);
        file.setCompression(compression);
        file.write(grids);
        file.close();
    } catch (const std::exception &e) {
        throw Error("cannot write \"" + out_vdb + "\": " + e.what());
    }
    vdb_tmp.commit();
    auto t2 = std::chrono::steady_clock::now();
    if (!opts.quiet) {
        uint64_t voxels = 0;
        for (const auto &g : grids)
            voxels += g->activeVoxelCount();
        std::printf("generated %s: %zu grid%s, %llu active voxels, %.0f ms; wrote %s, %.0f ms\n",
                    name.c_str(), grids.size(), grids.size() == 1 ? "" : "s",
                    (unsigned long long) voxels,
                    std::chrono::duration<double, std::milli>(t1 - t0).count(), out_vdb.c_str(),
                    std::chrono::duration<double, std::milli>(t2 - t1).count());
        std::fflush(stdout);
    }
    if (out_nvdb.empty())
        return ExitOk;
    return convert_grids(std::move(grids), "\"" + out_vdb + "\"", out_nvdb, opts);
}

} // namespace vdb2nvdb
