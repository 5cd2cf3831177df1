// src/loader/container.cpp -- the .nvdb file container (see container.h).
//
// ---------------------------------------------------------------------------
// Format facts relied upon (all little-endian; read with memcpy, never cast)
// ---------------------------------------------------------------------------
// Magics (8 bytes, "NanoVDB" + digit):
//   "NanoVDB0"  file/segment header AND grid magic up to NanoVDB 32.7;
//   "NanoVDB1"  grid magic (GridData.mMagic) from 32.8 on;
//   "NanoVDB2"  file/segment header magic from 32.8 on.
// A file is either
//  (a) one or more segments, back to back (NanoVDB 32.x util/IO.h, io/IO.h):
//        16-byte header: magic u64 @0, version u32 @8, grid count u16 @12,
//                        codec u16 @14 (0 NONE, 1 ZIP, 2 BLOSC);
//        per grid: a 176-byte metadata record immediately followed by its
//                  name (nameSize bytes incl. the '\0');
//        then the payloads of the segment's grids, in order.
//      Metadata record: gridSize u64 @0 (decoded bytes), fileSize u64 @8
//      (payload bytes in the file), nameKey @16, voxelCount @24,
//      gridType u32 @32, gridClass u32 @36, world bbox @40, index bbox @88,
//      voxel size @112, nameSize u32 @136, node counts @140, tile counts @156,
//      codec u16 @168, padding @170, version u32 @172.
//      The readers of 32.4-32.9 decode with the *segment header's* codec and
//      stamp the header's version on every grid; so do we (the per-grid codec
//      and version fields are ignored).
//  (b) since 32.6: a raw grid buffer, no header at all: one or more grids back
//      to back, each starting with its grid magic; their metadata comes from
//      GridData (name @40, 256 chars; mGridSize u64 @32; class u32 @632;
//      type u32 @636; version u32 @16).
// Payload codecs (identical in NanoVDB 32.4 util/IO.h and 32.6+ io/IO.h):
//   NONE   the grid bytes;
//   ZIP    [u64 compressed size][zlib stream] (zlib compress/uncompress);
//   BLOSC  the grid split into chunks of at most 1 GiB (2^30 bytes), each
//          [u64 compressed size][blosc1 block]; chunk k decodes to
//          min(remaining, 2^30) bytes.
// Version word: major << 21 | minor << 10 | patch; only major 32 is accepted.
//
// Readings chosen here
// --------------------
// * "NanoVDB0" at byte 0 starts both a segment header and (32.6/32.7) a raw
//   grid. A segment has its version at byte 8, a grid its checksum there and
//   its version at byte 16. We read segments when byte 8 holds a 32.x
//   version, a raw buffer when it does not and byte 16 does; if the segment
//   reading fails and the file also starts like a raw grid, the raw reading
//   is tried before the segment error is reported.
// * A segment payload may hold more than the grid its metadata describes:
//   fVDB 32.5 writes a batch of 4 grids as one grid "z" whose gridSize covers
//   all 4. read_grid() returns the whole decoded payload (gridSize bytes, as
//   NanoVDB's own readGrid does); the grid is the payload's first grid, and
//   validation uses that grid's own GridData.mGridSize.
// * Limits applied before allocating anything for an entry: gridSize in
//   [736, 2^34] bytes; NONE: gridSize == fileSize; ZIP/BLOSC: gridSize <=
//   fileSize * 1100. Compressed bytes are bounded by the file size.
// ---------------------------------------------------------------------------

#include <nanovdb_loader/container.h>

#include "detail.h"

#include <blosc.h>
#include <zlib.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>

namespace nanovdb_loader {

namespace detail {

constexpr uint64_t kFileHeaderSize = 16;  // sizeof(nanovdb::io::Header)
constexpr uint64_t kFileMetaSize   = 176; // sizeof(nanovdb::io::MetaData)
constexpr uint64_t kBloscChunk     = uint64_t(1) << 30; // io::Internal::MAX_SIZE
/// zlib's best ratio is about 1032:1 (blosc+LZ4 is lower); anything above
/// this is a forged header, rejected before allocating.
constexpr uint64_t kMaxCompressionRatio = 1100;

class File {
public:
    explicit File(const std::string &path) : m_path(path) {
        namespace fs = std::filesystem;
        std::error_code ec;
        fs::file_status st = fs::status(path, ec);
        if (ec || !fs::exists(st)) {
            if (ec && ec != std::errc::no_such_file_or_directory)
                fail(path, "cannot open file: " + ec.message());
            fail(path, "file not found");
        }
        if (fs::is_directory(st))
            fail(path, "is a directory, not a NanoVDB file");
        errno = 0;
        m_in.open(path, std::ios::in | std::ios::binary);
        if (!m_in.is_open())
            fail(path, std::string("cannot open file for reading: ") +
                           (errno ? std::strerror(errno) : "unknown error"));
        m_in.seekg(0, std::ios::end);
        std::streamoff end = m_in.tellg();
        if (!m_in || end < 0)
            fail(path, "cannot determine the file size (not a regular file?)");
        m_size = uint64_t(end);
    }

    uint64_t size() const { return m_size; }

    /// Reads exactly `n` bytes at `offset`; the caller has checked the range
    /// against size(). Fails (e.g. file shrank meanwhile) with `what`.
    void read_at(uint64_t offset, void *dst, uint64_t n, const char *what) {
        if (offset > m_size || n > m_size - offset)
            fail(m_path, std::string("truncated ") + what + ": needs bytes [" +
                             std::to_string(offset) + ", " + std::to_string(offset + n) +
                             ") but the file has " + std::to_string(m_size) + " bytes");
        m_in.clear();
        m_in.seekg(std::streamoff(offset), std::ios::beg);
        char *out = static_cast<char *>(dst);
        // Read in pieces so that a streamsize never overflows.
        while (n > 0) {
            const uint64_t piece = std::min<uint64_t>(n, uint64_t(1) << 30);
            m_in.read(out, std::streamsize(piece));
            if (uint64_t(m_in.gcount()) != piece)
                fail(m_path, std::string("read error or truncated ") + what +
                                 " at byte " + std::to_string(offset));
            out += piece;
            offset += piece;
            n -= piece;
        }
    }

private:
    std::string m_path;
    std::ifstream m_in;
    uint64_t m_size = 0;
};

/// Limits on a grid entry, enforced before anything is allocated for it.
void check_entry_sizes(const std::string &path, const GridEntry &e,
                              const std::string &which) {
    if (e.grid_size < layout::GRID_HEADER_SIZE)
        fail(path, which + ": grid size " + std::to_string(e.grid_size) +
                       " bytes is smaller than a grid's 736-byte header (GridData + TreeData)");
    if (e.grid_size > kMaxGridBytes)
        fail(path, which + ": grid size " + std::to_string(e.grid_size) +
                       " bytes exceeds the 16 GiB (2^34 bytes) limit of the reader "
                       "(32-bit word addresses)");
    switch (e.codec) {
        case Codec::None:
            if (e.grid_size != e.file_size)
                fail(path, which + ": uncompressed grid size " + std::to_string(e.grid_size) +
                               " bytes differs from its payload size in the file (" +
                               std::to_string(e.file_size) + " bytes)");
            break;
        case Codec::Zip:
        case Codec::Blosc:
            if (e.file_size <= 8)
                fail(path, which + ": compressed payload of " + std::to_string(e.file_size) +
                               " bytes is too small to hold a " +
                               codec_name(uint16_t(e.codec)) + " stream");
            if (e.grid_size / kMaxCompressionRatio > e.file_size)
                fail(path, which + ": grid size " + std::to_string(e.grid_size) +
                               " bytes is implausible for a " + std::to_string(e.file_size) +
                               "-byte " + codec_name(uint16_t(e.codec)) +
                               " payload (ratio above 1100:1)");
            break;
    }
}

std::string entry_label(size_t index, const std::string &name) {
    return "grid " + std::to_string(index) + " \"" + name + "\"";
}

/// Parses consecutive segments starting at byte 0.
std::vector<GridEntry> parse_segments(const std::string &path, File &f) {
    std::vector<GridEntry> grids;
    const uint64_t size = f.size();
    uint64_t offset = 0;
    for (uint32_t seg = 0; offset < size; ++seg) {
        const std::string where = "segment " + std::to_string(seg) + " (at byte " +
                                  std::to_string(offset) + ")";
        if (size - offset < kFileHeaderSize)
            fail(path, where + ": truncated segment header: " + std::to_string(size - offset) +
                           " bytes left, a header needs 16");
        uint8_t h[kFileHeaderSize];
        f.read_at(offset, h, kFileHeaderSize, "segment header");
        const uint64_t magic   = load<uint64_t>(h + 0);
        const uint32_t version = load<uint32_t>(h + 8);
        const uint16_t count   = load<uint16_t>(h + 12);
        const uint16_t codec   = load<uint16_t>(h + 14);
        if (is_byte_swapped_magic(magic))
            fail(path, where + ": byte-swapped NanoVDB magic " + describe_magic(magic) +
                           ": the file was written on a big-endian machine; only "
                           "little-endian files are supported");
        if (magic != layout::MAGIC_NUMBER && magic != layout::MAGIC_FILE)
            fail(path, where + ": expected a NanoVDB segment header (\"NanoVDB0\" or "
                               "\"NanoVDB2\"), found " + describe_magic(magic));
        if (version_major(version) != layout::MAJOR_VERSION_NUMBER)
            fail(path, where + ": NanoVDB file version " + version_string(version) +
                           " (major " + std::to_string(version_major(version)) +
                           "); only major version 32 is supported");
        if (codec > 2)
            fail(path, where + ": unknown codec " + std::to_string(codec) +
                           " (known: 0 NONE, 1 ZIP, 2 BLOSC)");
        if (count == 0)
            fail(path, where + ": segment declares zero grids");

        uint64_t pos = offset + kFileHeaderSize;
        if (uint64_t(count) * kFileMetaSize > size - pos)
            fail(path, where + ": truncated metadata: " + std::to_string(count) +
                           " grids need " + std::to_string(uint64_t(count) * kFileMetaSize) +
                           " bytes of metadata, only " + std::to_string(size - pos) + " remain");
        const size_t first = grids.size();
        for (uint16_t i = 0; i < count; ++i) {
            const size_t index = grids.size();
            uint8_t m[kFileMetaSize];
            if (size - pos < kFileMetaSize)
                fail(path, where + ": truncated metadata of grid " + std::to_string(index) +
                               " at byte " + std::to_string(pos));
            f.read_at(pos, m, kFileMetaSize, "grid metadata");
            pos += kFileMetaSize;
            const uint32_t name_size = load<uint32_t>(m + 136);
            if (name_size > size - pos)
                fail(path, where + ": truncated name of grid " + std::to_string(index) +
                               ": " + std::to_string(name_size) + " bytes at byte " +
                               std::to_string(pos) + " but only " +
                               std::to_string(size - pos) + " remain");
            std::string name;
            if (name_size > 0) {
                std::vector<uint8_t> buf(name_size);
                f.read_at(pos, buf.data(), name_size, "grid name");
                name = fixed_string(buf.data(), name_size);
            }
            pos += name_size;

            GridEntry e;
            e.name        = std::move(name);
            e.grid_size   = load<uint64_t>(m + 0);
            e.file_size   = load<uint64_t>(m + 8);
            e.grid_type   = load<uint32_t>(m + 32);
            e.grid_class  = load<uint32_t>(m + 36);
            e.file_offset = 0; // set below, once all names are known
            e.codec       = Codec(codec);
            e.version     = version;
            e.segment     = seg;
            e.raw         = false;
            grids.push_back(std::move(e));
        }
        // Payloads follow the metadata, in order.
        for (size_t i = first; i < grids.size(); ++i) {
            GridEntry &e = grids[i];
            const std::string which = entry_label(i, e.name) + " in " + where;
            e.file_offset = pos;
            if (e.file_size > size - pos)
                fail(path, which + ": payload of " + std::to_string(e.file_size) +
                               " bytes at byte " + std::to_string(pos) +
                               " extends beyond the end of the file (" +
                               std::to_string(size) + " bytes)");
            check_entry_sizes(path, e, which);
            pos += e.file_size;
        }
        offset = pos;
    }
    if (grids.empty())
        fail(path, "the file holds no grids");
    return grids;
}

/// Does the file start like a raw grid buffer (32.6+) rather than a segment?
/// Only the header fields are checked; parse_raw() then reports precisely
/// what is wrong (e.g. a truncated grid).
bool looks_like_raw_grid(File &f) {
    if (f.size() < layout::GRID_SIZE)
        return false;
    uint8_t g[layout::GRID_SIZE];
    f.read_at(0, g, layout::GRID_SIZE, "grid header");
    const uint64_t magic = load<uint64_t>(g + layout::GRID_OFF_MAGIC);
    return (magic == layout::MAGIC_NUMBER || magic == layout::MAGIC_GRID) &&
           version_major(load<uint32_t>(g + layout::GRID_OFF_VERSION)) == layout::MAJOR_VERSION_NUMBER &&
           load<uint32_t>(g + layout::GRID_OFF_GRID_TYPE) < 1024 &&
           load<uint32_t>(g + layout::GRID_OFF_GRID_CLASS) < 1024;
}

/// Parses a raw grid buffer: grids back to back, each described by its GridData.
std::vector<GridEntry> parse_raw(const std::string &path, File &f) {
    std::vector<GridEntry> grids;
    const uint64_t size = f.size();
    uint64_t offset = 0;
    while (offset < size) {
        const size_t index = grids.size();
        const std::string where = "raw grid buffer, grid " + std::to_string(index) +
                                  " (at byte " + std::to_string(offset) + ")";
        if (size - offset < layout::GRID_SIZE)
            fail(path, where + ": truncated grid header: " + std::to_string(size - offset) +
                           " bytes left, a grid header needs 672");
        uint8_t g[layout::GRID_SIZE];
        f.read_at(offset, g, layout::GRID_SIZE, "grid header");
        const uint64_t magic = load<uint64_t>(g + layout::GRID_OFF_MAGIC);
        const uint32_t version = load<uint32_t>(g + layout::GRID_OFF_VERSION);
        if (is_byte_swapped_magic(magic))
            fail(path, where + ": byte-swapped NanoVDB magic " + describe_magic(magic) +
                           ": only little-endian files are supported");
        if (magic != layout::MAGIC_NUMBER && magic != layout::MAGIC_GRID)
            fail(path, where + ": expected a grid magic (\"NanoVDB0\" or \"NanoVDB1\"), found " +
                           describe_magic(magic));
        if (version_major(version) != layout::MAJOR_VERSION_NUMBER)
            fail(path, where + ": NanoVDB grid version " + version_string(version) +
                           " (major " + std::to_string(version_major(version)) +
                           "); only major version 32 is supported");
        GridEntry e;
        e.name        = fixed_string(g + layout::GRID_OFF_GRID_NAME, layout::GRID_NAME_SIZE);
        e.grid_type   = load<uint32_t>(g + layout::GRID_OFF_GRID_TYPE);
        e.grid_class  = load<uint32_t>(g + layout::GRID_OFF_GRID_CLASS);
        e.grid_size   = load<uint64_t>(g + layout::GRID_OFF_GRID_SIZE);
        e.file_offset = offset;
        e.file_size   = e.grid_size;
        e.codec       = Codec::None;
        e.version     = version;
        e.segment     = 0;
        e.raw         = true;
        const std::string which = entry_label(index, e.name) + " (" + where + ")";
        check_entry_sizes(path, e, which);
        if (e.grid_size > size - offset)
            fail(path, which + ": GridData.mGridSize = " + std::to_string(e.grid_size) +
                           " bytes extends beyond the end of the file (" +
                           std::to_string(size) + " bytes)");
        offset += e.grid_size;
        grids.push_back(std::move(e));
    }
    return grids;
}


} // namespace detail

// ---- File level ----------------------------------------------------------------

/// Human name of a NanoVDB GridType value (32.6+ numbering, a superset of
/// the 32.4 table; the names of 32.4's toStr, with 32.x's Fp4... spelling).
std::string grid_class_name(uint32_t grid_class) {
    // NanoVDB's GridClass (PNANOVDB_GRID_CLASS_*)
    static const char *names[] = { "unknown", "level set", "fog volume", "staggered",
                                   "point index", "point data", "topology", "voxel volume",
                                   "index grid", "tensor grid" };
    constexpr uint32_t n = uint32_t(sizeof(names) / sizeof(names[0]));
    return grid_class < n ? names[grid_class] : "unknown (" + std::to_string(grid_class) + ")";
}

std::string grid_type_name(uint32_t grid_type) {
    static const char *names[] = {
        "unknown",  "float",     "double",      "int16",      "int32",   "int64",
        "Vec3f",    "Vec3d",     "Mask",        "Half",       "uint32",  "bool",
        "RGBA8",    "Fp4",       "Fp8",         "Fp16",       "FpN",     "Vec4f",
        "Vec4d",    "Index",     "OnIndex",     "IndexMask",  "OnIndexMask",
        "PointIndex", "Vec3u8",  "Vec3u16",     "UInt8" };
    constexpr uint32_t n = uint32_t(sizeof(names) / sizeof(names[0]));
    if (grid_type == 0 || grid_type >= n)
        return "unknown (" + std::to_string(grid_type) + ")";
    return names[grid_type];
}

std::string supported_grid_types() {
    std::string s;
    for (const layout::ValueType &t : layout::VALUE_TYPES)
        s += std::string(s.empty() ? "" : ", ") + t.name;
    return s;
}

/// `0: "density" (float), 1: "temperature" (float)`
std::string describe_grids(const std::vector<GridEntry> &grids) {
    std::string s;
    for (size_t i = 0; i < grids.size(); ++i) {
        if (i) s += ", ";
        s += std::to_string(i) + ": \"" + grids[i].name + "\" (" +
             grid_type_name(grids[i].grid_type) + ")";
    }
    return s;
}

/// Parses all segment headers and metadata (never the payloads).
std::vector<GridEntry> list_grids(const std::string &path) {
    detail::File f(path);
    const uint64_t size = f.size();
    if (size == 0)
        detail::fail(path, "the file is empty (0 bytes), not a NanoVDB file");
    uint8_t head[8] = {};
    const uint64_t nhead = std::min<uint64_t>(size, 8);
    f.read_at(0, head, nhead, "file header");
    if (size < 8)
        detail::fail(path, "not a NanoVDB file: only " + std::to_string(size) +
                               " bytes long (first bytes: " +
                               detail::describe_bytes(head, size_t(nhead)) + ")");
    const uint64_t magic = detail::load<uint64_t>(head);
    if (detail::is_byte_swapped_magic(magic))
        detail::fail(path, "byte-swapped NanoVDB magic " + detail::describe_magic(magic) +
                               ": the file was written on a big-endian machine; only "
                               "little-endian files are supported");
    if (magic == layout::MAGIC_GRID) // only ever a grid magic: raw grid buffer
        return detail::parse_raw(path, f);
    if (magic == layout::MAGIC_FILE) // only ever a file magic: segments
        return detail::parse_segments(path, f);
    if (magic != layout::MAGIC_NUMBER) {
        std::string hint;
        if (std::memcmp(head, " BDV", 4) == 0)
            hint = "; this is an OpenVDB .vdb file: convert it to .nvdb first";
        detail::fail(path, "not a NanoVDB file: the first 8 bytes are " +
                               detail::describe_bytes(head, 8) +
                               ", expected \"NanoVDB0\", \"NanoVDB1\" or \"NanoVDB2\"" + hint);
    }
    // "NanoVDB0": a segment header or a 32.6/32.7 raw grid (see "Readings
    // chosen here" at the top of this file).
    bool seg_version_ok = false;
    if (size >= 12) {
        uint8_t v[4];
        f.read_at(8, v, 4, "file header");
        seg_version_ok = detail::version_major(detail::load<uint32_t>(v)) == layout::MAJOR_VERSION_NUMBER;
    }
    if (seg_version_ok) {
        try {
            return detail::parse_segments(path, f);
        } catch (const Error &) {
            if (!detail::looks_like_raw_grid(f))
                throw;
            try {
                return detail::parse_raw(path, f);
            } catch (const Error &) {
            }
            throw; // report the segment reading's error
        }
    }
    if (detail::looks_like_raw_grid(f))
        return detail::parse_raw(path, f);
    return detail::parse_segments(path, f); // throws, naming the version found
}

/// Chooses a grid: empty selector -> the first grid of a supported type;
/// otherwise a name, or failing that a non-negative decimal index. Only the
/// supported types (layout.h's VALUE_TYPES) are accepted.
const GridEntry &select_grid(const std::string &path,
                                    const std::vector<GridEntry> &grids,
                                    const std::string &selector) {
    if (grids.empty())
        detail::fail(path, "the file holds no grids");
    const GridEntry *chosen = nullptr;
    size_t index = 0;
    if (selector.empty()) {
        for (size_t i = 0; i < grids.size(); ++i)
            if (layout::value_type(grids[i].grid_type)) return grids[i];
        detail::fail(path, "no grid of a supported type in the file (supported types: " +
                           supported_grid_types() + "); the file holds: " +
                           describe_grids(grids));
    }
    for (size_t i = 0; i < grids.size() && !chosen; ++i)
        if (grids[i].name == selector) { chosen = &grids[i]; index = i; }
    if (!chosen) {
        const bool digits = selector.size() <= 18 &&
            std::all_of(selector.begin(), selector.end(),
                        [](char c) { return c >= '0' && c <= '9'; });
        if (digits) {
            const uint64_t i = std::stoull(selector);
            if (i < grids.size()) { chosen = &grids[size_t(i)]; index = size_t(i); }
        }
    }
    if (!chosen)
        detail::fail(path, "grid \"" + selector + "\" not found (neither a grid name nor "
                           "a valid index); the file holds: " + describe_grids(grids));
    if (!layout::value_type(chosen->grid_type))
        detail::fail(path, detail::entry_label(index, chosen->name) + " has type " +
                               grid_type_name(chosen->grid_type) +
                               ", which is not supported (supported types: " +
                               supported_grid_types() + ")");
    return *chosen;
}

/// select_grid(), and the 6-channel pair "X[0:3]", "X[3:6]" (container.h)
GridChoice select_grids(const std::string &path, const std::vector<GridEntry> &grids,
                        const std::string &selector) {
    auto named = [&](const std::string &name) -> const GridEntry * {
        for (const GridEntry &e : grids)
            if (e.name == name)
                return &e;
        return nullptr;
    };
    auto ends_with = [](const std::string &s, const char *tail) {
        const size_t n = std::strlen(tail);
        return s.size() > n && s.compare(s.size() - n, n, tail) == 0;
    };
    std::string base = selector;
    if (selector.empty() && !grids.empty()) {
        const GridEntry &chosen = select_grid(path, grids, "");
        if (ends_with(chosen.name, "[0:3]"))
            base = chosen.name.substr(0, chosen.name.size() - 5);
    }
    GridChoice c;
    if (!base.empty() && !named(base) && named(base + "[0:3]") && named(base + "[3:6]")) {
        c.first = named(base + "[0:3]");
        c.second = named(base + "[3:6]");
        for (const GridEntry *e : { c.first, c.second })
            if (e->grid_type != layout::GRID_TYPE_VEC3F)
                detail::fail(path, "the 6-channel pair \"" + base + "[0:3]\", \"" + base +
                                   "[3:6]\" must be two Vec3f grids; \"" + e->name + "\" is " +
                                   grid_type_name(e->grid_type));
        c.name = base;
    } else {
        c.first = &select_grid(path, grids, selector);
        c.name = c.first->name;
    }
    return c;
}

/// Reads and decodes one grid's payload into `dst` (>= entry.grid_size bytes).
void read_grid(const std::string &path, const GridEntry &entry, void *dst) {
    using namespace detail;
    const std::string which = "grid \"" + entry.name + "\" (payload at byte " +
                              std::to_string(entry.file_offset) + ")";
    if (uint16_t(entry.codec) > 2)
        fail(path, which + ": unknown codec " + std::to_string(uint16_t(entry.codec)));
    check_entry_sizes(path, entry, which);
    File f(path);
    if (entry.file_offset > f.size() || entry.file_size > f.size() - entry.file_offset)
        fail(path, which + ": truncated payload: needs bytes [" +
                       std::to_string(entry.file_offset) + ", " +
                       std::to_string(entry.file_offset + entry.file_size) +
                       ") but the file has " + std::to_string(f.size()) + " bytes");
    uint8_t *out = static_cast<uint8_t *>(dst);

    if (entry.codec == Codec::None) {
        f.read_at(entry.file_offset, out, entry.grid_size, "payload");
        return;
    }

    uint64_t pos = entry.file_offset;
    const uint64_t end = entry.file_offset + entry.file_size;
    auto read_size_prefix = [&](const std::string &what) {
        if (end - pos < 8)
            fail(path, which + ": truncated payload: no room for the " + what +
                           " size at byte " + std::to_string(pos));
        uint8_t b[8];
        f.read_at(pos, b, 8, "payload");
        pos += 8;
        const uint64_t n = load<uint64_t>(b);
        if (n > end - pos)
            fail(path, which + ": truncated payload: " + what + " of " + std::to_string(n) +
                           " bytes at byte " + std::to_string(pos) + " extends past the " +
                           std::to_string(entry.file_size) + "-byte payload");
        return n;
    };

    if (entry.codec == Codec::Zip) {
        const uint64_t csize = read_size_prefix("zlib stream");
        std::vector<uint8_t> src(static_cast<size_t>(csize));
        f.read_at(pos, src.data(), csize, "zlib stream");
        uLongf out_len = uLongf(entry.grid_size);
        const int status = uncompress(out, &out_len, src.data(), uLong(csize));
        if (status == Z_BUF_ERROR && out_len == uLongf(entry.grid_size))
            fail(path, which + ": zlib stream decodes to more than the grid size of " +
                           std::to_string(entry.grid_size) + " bytes (or is truncated)");
        if (status != Z_OK)
            fail(path, which + ": corrupt zlib stream (zlib error " + std::to_string(status) +
                           ": " + zError(status) + ")");
        if (uint64_t(out_len) != entry.grid_size)
            fail(path, which + ": zlib stream decodes to " + std::to_string(out_len) +
                           " bytes, but the metadata says the grid has " +
                           std::to_string(entry.grid_size));
        return;
    }

    // BLOSC: chunks of at most 1 GiB, each [u64 size][blosc block].
    uint64_t done = 0;
    for (uint64_t chunk_index = 0; done < entry.grid_size; ++chunk_index) {
        const std::string what = "blosc chunk " + std::to_string(chunk_index);
        const uint64_t expect = std::min<uint64_t>(entry.grid_size - done, kBloscChunk);
        const uint64_t csize = read_size_prefix(what);
        if (csize < BLOSC_MIN_HEADER_LENGTH)
            fail(path, which + ": " + what + " of " + std::to_string(csize) +
                           " bytes is smaller than a blosc header");
        std::vector<uint8_t> src(static_cast<size_t>(csize));
        f.read_at(pos, src.data(), csize, "blosc chunk");
        pos += csize;
        size_t nbytes = 0;
        if (blosc_cbuffer_validate(src.data(), size_t(csize), &nbytes) != 0)
            fail(path, which + ": corrupt " + what + " (invalid blosc header)");
        if (uint64_t(nbytes) != expect)
            fail(path, which + ": " + what + " decodes to " + std::to_string(nbytes) +
                           " bytes, expected " + std::to_string(expect) +
                           " (grid size " + std::to_string(entry.grid_size) + ")");
        const int count = blosc_decompress_ctx(src.data(), out + done, size_t(expect), 1);
        if (count <= 0 || uint64_t(count) != expect)
            fail(path, which + ": corrupt " + what + " (blosc error " + std::to_string(count) +
                           ")");
        done += expect;
    }
}

} // namespace nanovdb_loader
