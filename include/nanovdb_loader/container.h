// nanovdb_loader/container.h -- the .nvdb file container: which grids a file
// holds (segments, metadata, raw grid buffers), selecting one, and reading and
// decoding its payload (NONE / ZIP / BLOSC). The bytes of one grid come out;
// what they mean is validation.h's business.
//
// Every failure throws nanovdb_loader::Error whose message starts with
// "\"<path>\": ". Nothing is allocated beyond what the file's own size can
// justify, and no byte outside the file is ever read. The format facts relied
// upon are listed at the top of src/loader/container.cpp.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace nanovdb_loader {

/// Every message starts with "\"<path>\": " and then says what is wrong.
struct Error : std::runtime_error { using std::runtime_error::runtime_error; };

/// Payload codec of a segment (numbering of nanovdb::io::Codec).
enum class Codec : uint16_t { None = 0, Zip = 1, Blosc = 2 };

/// One grid of a file, as described by its metadata (payload not read).
struct GridEntry {
    std::string name;        ///< may be empty
    uint32_t grid_type;      ///< NanoVDB GridType value from the metadata
    uint32_t grid_class;     ///< NanoVDB GridClass value from the metadata
    uint64_t grid_size;      ///< decoded size of the grid buffer in bytes
    uint64_t file_offset;    ///< byte offset of the payload in the file
    uint64_t file_size;      ///< payload bytes in the file
    Codec    codec;
    uint32_t version;        ///< packed (major << 21 | minor << 10 | patch)
    uint32_t segment;        ///< index of the segment it came from
    bool     raw;            ///< file is a raw grid buffer without segment header
};


/// Human name of a NanoVDB GridType value ("float", "Vec3f", "Fp16", ...)
std::string grid_type_name(uint32_t grid_type);
/// "level set", "fog volume", ... for a NanoVDB GridClass value
std::string grid_class_name(uint32_t grid_class);
/// "float, Half, Fp4, Fp8, Fp16, FpN, Vec3f": the types a grid may have
std::string supported_grid_types();

/// `0: "density" (float), 1: "temperature" (float)`
std::string describe_grids(const std::vector<GridEntry> &grids);

/// Parses all segment headers and metadata (never the payloads).
std::vector<GridEntry> list_grids(const std::string &path);

/// Chooses a grid: empty selector -> first float grid; otherwise a name, or
/// failing that a non-negative decimal index. Only float grids are accepted.
const GridEntry &select_grid(const std::string &path, const std::vector<GridEntry> &grids,
                             const std::string &selector);

/// Reads and decodes one grid's payload into `dst` (>= entry.grid_size bytes).
void read_grid(const std::string &path, const GridEntry &entry, void *dst);

} // namespace nanovdb_loader
