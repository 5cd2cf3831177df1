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

/// Text from a file (a grid name, a reader's message) made safe to show:
/// valid UTF-8 is kept, and control characters and bytes that are not
/// UTF-8 become \xNN. (A damaged name with a stray 0xF5 once made the
/// Python binding fail to decode the whole error, file name included.)
inline std::string printable_text(const std::string &s) {
    static const char hex[] = "0123456789ABCDEF";
    std::string out;
    out.reserve(s.size());
    const auto *p = reinterpret_cast<const unsigned char *>(s.data());
    const size_t n = s.size();
    for (size_t i = 0; i < n;) {
        const unsigned char c = p[i];
        size_t len = c < 0x80 ? 1 : (c >= 0xC2 && c <= 0xDF) ? 2
                   : (c >= 0xE0 && c <= 0xEF) ? 3 : (c >= 0xF0 && c <= 0xF4) ? 4 : 0;
        bool ok = len > 0 && i + len <= n;
        for (size_t k = 1; ok && k < len; ++k)
            ok = (p[i + k] & 0xC0) == 0x80;
        // (no overlong or surrogate forms, nothing past U+10FFFF)
        if (ok && len == 3)
            ok = !(c == 0xE0 && p[i + 1] < 0xA0) && !(c == 0xED && p[i + 1] >= 0xA0);
        if (ok && len == 4)
            ok = !(c == 0xF0 && p[i + 1] < 0x90) && !(c == 0xF4 && p[i + 1] >= 0x90);
        if (ok && len == 1 && (c < 0x20 || c == 0x7F) && c != '\n' && c != '\t')
            ok = false;
        if (ok) {
            out.append(s, i, len);
            i += len;
        } else {
            out += "\\x";
            out += hex[c >> 4];
            out += hex[c & 15];
            i += 1;
        }
    }
    return out;
}

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

/// The grid or grids a volume reads (select_grids)
struct GridChoice {
    const GridEntry *first = nullptr;  ///< the grid (a pair: channels 0-2)
    const GridEntry *second = nullptr; ///< a pair's channels 3-5, else null
    std::string name;                  ///< the pair's base name X, else first->name
};

/// select_grid(), and the 6-channel pair: where a grid X is asked for (or
/// none is, and the default is "X[0:3]") and the file holds "X[0:3]" and
/// "X[3:6]" but no X, those two (both must be Vec3f grids)
GridChoice select_grids(const std::string &path, const std::vector<GridEntry> &grids,
                        const std::string &selector);

/// Reads and decodes one grid's payload into `dst` (>= entry.grid_size bytes).
void read_grid(const std::string &path, const GridEntry &entry, void *dst);

} // namespace nanovdb_loader
