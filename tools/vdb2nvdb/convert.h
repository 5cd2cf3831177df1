// vdb2nvdb: conversion of OpenVDB float grids to NanoVDB, verification of the
// written file against OpenVDB, statistics and the dense Mitsuba .vol export.
//
// Conventions (as in src/volumes/grid_nanovdb.cpp): values sit at integer
// index coordinates; index bounding boxes are inclusive on the upper end
// ([min, max]); a voxel's cell is [ijk - 0.5, ijk + 0.5] in index space.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include <openvdb/openvdb.h>
#include <nanovdb/util/IO.h>

namespace vdb2nvdb {

/// Exit codes of the CLI.
enum Exit : int { ExitOk = 0, ExitError = 1, ExitUsage = 2, ExitVerify = 3 };

/// An error with a message for the user and an exit code.
struct Error : std::runtime_error {
    int code;
    explicit Error(const std::string &msg, int code = ExitError)
        : std::runtime_error(msg), code(code) {}
};

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

const char *quantize_name(Quantize q);

/// vdb2nvdb IN.vdb OUT.nvdb: reads `in`, converts, writes `out`. Returns an
/// exit code; throws Error for bad input (nothing is left at `out` then).
int convert_file(const std::string &in, const std::string &out, const Options &opts);

/// The same for grids already in memory (the generator); `label` names their
/// source in messages. The grids may be modified (level set -> fog).
int convert_grids(openvdb::GridPtrVec grids, const std::string &label,
                  const std::string &out, const Options &opts);

/// vdb2nvdb --verify-only IN.vdb OUT.nvdb: checks an existing .nvdb against
/// the .vdb it was converted from with the same options.
int verify_only(const std::string &in, const std::string &nvdb, const Options &opts);

/// vdb2nvdb --list IN.vdb
int list_file(const std::string &in);

/// Reads every grid of a .vdb file (Error naming the file on failure).
openvdb::GridPtrVec read_vdb(const std::string &path);

/// Physical memory in bytes (0 if unknown).
uint64_t physical_memory();

/// Writes `path` through a temporary file in the same directory that is
/// renamed into place by commit(); removed if never committed (also on
/// SIGINT/SIGTERM).
class TempFile {
public:
    explicit TempFile(const std::string &path);
    ~TempFile();
    TempFile(const TempFile &) = delete;
    TempFile &operator=(const TempFile &) = delete;
    const std::string &tmp_path() const { return m_tmp; }
    const std::string &path() const { return m_path; }
    void commit();
    void discard();
private:
    std::string m_path, m_tmp;
    bool m_done = false;
    int m_slot = -1;
};

/// Installs SIGINT/SIGTERM handlers that remove live temporary files.
void install_signal_handlers();

} // namespace vdb2nvdb
