// vdb2nvdb's command-line options, as tools/vdb2nvdb/main.cpp parses them.
// The conversion steps (src/convert/) read grids, keep_level_sets,
// tolerance and quiet, the first two of which the .vdb reader
// (src/loader/vdb_read.cpp) sets; the others are the tool's alone.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <openvdb/openvdb.h>
#include <nanovdb/util/IO.h>

namespace vdb2nvdb {

enum class Quantize { Float, Fp4, Fp8, Fp16, FpN };

struct Options {
    std::vector<std::string> grids;      ///< --grid (empty: every float grid)
    bool keep_level_sets = false;        ///< --keep-level-sets
    Quantize quantize = Quantize::Float; ///< --quantize
    float tolerance = -1.f;              ///< --tolerance (fpn; < 0: NanoVDB's default)
    nanovdb::io::Codec codec = nanovdb::io::Codec::NONE; ///< --codec
    uint64_t verify = 100000;            ///< --verify N (0: off)
    uint64_t seed = 1;                   ///< --seed (verification samples)
    bool stats = false;                  ///< --stats
    std::string dense;                   ///< --dense OUT.vol
    uint64_t max_dense_bytes = 0;        ///< --max-dense-bytes (0: half the physical memory)
    std::vector<openvdb::Coord> probes;  ///< --probe i,j,k
    bool corrupt_for_test = false;       ///< hidden: simulate a conversion bug
    bool quiet = false;                  ///< --quiet
};

/// The --quantize name of q
inline const char *quantize_name(Quantize q) {
    switch (q) {
        case Quantize::Float: return "float";
        case Quantize::Fp4: return "fp4";
        case Quantize::Fp8: return "fp8";
        case Quantize::Fp16: return "fp16";
        case Quantize::FpN: return "fpn";
    }
    return "?";
}

} // namespace vdb2nvdb
