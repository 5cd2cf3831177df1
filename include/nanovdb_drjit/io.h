// nanovdb_drjit/io.h -- host-side loader for NanoVDB `.nvdb` files.
//
// Plain C++17 + zlib + c-blosc. It parses the file format itself (no NanoVDB
// C++ headers, no Dr.Jit), so that the plugin can read files written by any
// NanoVDB 32.x writer, and it validates a float grid buffer so that the
// PNanoVDB-style traversal (root -> upper -> lower -> leaf) never leaves it.
//
// Every failure throws io::Error whose message starts with "\"<path>\": ".
// Nothing is allocated beyond what the file's own size can justify, and no
// byte outside a buffer is ever read.
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
// Float grid layout: NanoVDB 32.4 PNanoVDB.h, PNANOVDB_GRID_SIZE,
// PNANOVDB_TREE_*, PNANOVDB_ROOT_*, and row 1 (float) of
// pnanovdb_grid_type_constants. The same numbers hold for every 32.x version.
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
//   validate_float_grid() uses that grid's own GridData.mGridSize.
// * The validator also requires the grid/tree header, the root with its
//   tile table and the three node arrays to be disjoint, and every child
//   offset to land exactly on a node of the level below: so a child can never
//   be its own parent, the root, or a node of the wrong level, and the
//   traversal's fixed depth (root -> upper -> lower -> leaf) allows no loop.
// * Values (scan_values(), sanitize_values(), at the end of this file): NaN,
//   +-Inf and negatives are counted and located (index coordinate of the
//   first one), and can be replaced in place; the plugin chooses the policy.
// * Limits applied before allocating anything for an entry: gridSize in
//   [736, 2^34] bytes; NONE: gridSize == fileSize; ZIP/BLOSC: gridSize <=
//   fileSize * 1100. Compressed bytes are bounded by the file size.
// ---------------------------------------------------------------------------
#pragma once

#include <blosc.h>
#include <zlib.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace nanovdb_drjit::io {

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

/// Summary of a validated float grid (see validate_float_grid()).
struct FloatGridInfo {
    uint32_t root_word;                 ///< byte offset of the root node / 4
    int32_t  bbox_min[3], bbox_max[3];  ///< root's active index bbox, inclusive
    bool     empty;                     ///< bbox_min > bbox_max on some axis
    float    background;
    /// min / max over every value a lookup can return: background, root tiles
    /// without child, upper/lower table entries whose child bit is 0, all 512
    /// values of every leaf. NaNs are skipped (and counted); if every value is
    /// NaN both are NaN. +-Inf values are included (and counted).
    float    value_min, value_max;
    uint64_t nan_count, inf_count;
    double   map_mat[9], map_inv[9], map_vec[3]; ///< index->world, row-major
    double   voxel_size[3];
    uint32_t grid_class;
    std::string name;
    uint32_t node_count[3];             ///< leaf, lower, upper
    uint64_t active_voxel_count;
};

namespace detail {

// ---- Constants --------------------------------------------------------------

constexpr uint64_t kMagicNumb = 0x304244566f6e614eull; // "NanoVDB0"
constexpr uint64_t kMagicGrid = 0x314244566f6e614eull; // "NanoVDB1" (32.8+ grids)
constexpr uint64_t kMagicFile = 0x324244566f6e614eull; // "NanoVDB2" (32.8+ files)
constexpr uint32_t kMajorVersion = 32;

constexpr uint64_t kFileHeaderSize = 16;  // sizeof(nanovdb::io::Header)
constexpr uint64_t kFileMetaSize   = 176; // sizeof(nanovdb::io::MetaData)
constexpr uint64_t kBloscChunk     = uint64_t(1) << 30; // io::Internal::MAX_SIZE

/// Largest decoded grid we accept: the reader addresses 32-bit words (16 GiB).
constexpr uint64_t kMaxGridBytes = uint64_t(1) << 34;
/// zlib's best ratio is about 1032:1 (blosc+LZ4 is lower); anything above
/// this is a forged header, rejected before allocating.
constexpr uint64_t kMaxCompressionRatio = 1100;

// PNanoVDB 32.4: PNANOVDB_GRID_OFF_* (GridData, 672 bytes).
constexpr uint64_t kGridOffMagic      = 0;
constexpr uint64_t kGridOffVersion    = 16;
constexpr uint64_t kGridOffGridSize   = 32;
constexpr uint64_t kGridOffName       = 40;
constexpr uint64_t kGridNameSize      = 256;
constexpr uint64_t kGridOffMap        = 296;
constexpr uint64_t kGridOffVoxelSize  = 608;
constexpr uint64_t kGridOffGridClass  = 632;
constexpr uint64_t kGridOffGridType   = 636;
constexpr uint64_t kGridSize          = 672;
// PNANOVDB_MAP_OFF_MATD / INVMATD / VECD (double members of the Map).
constexpr uint64_t kMapOffMatD = 88, kMapOffInvMatD = 160, kMapOffVecD = 232;
// PNANOVDB_TREE_* (TreeData, 64 bytes, right after GridData). Node offsets
// are u64 bytes relative to the tree.
constexpr uint64_t kTreeOffNodeOffsetLeaf  = 0;
constexpr uint64_t kTreeOffNodeOffsetLower = 8;
constexpr uint64_t kTreeOffNodeOffsetUpper = 16;
constexpr uint64_t kTreeOffNodeOffsetRoot  = 24;
constexpr uint64_t kTreeOffNodeCountLeaf   = 32;
constexpr uint64_t kTreeOffNodeCountLower  = 36;
constexpr uint64_t kTreeOffNodeCountUpper  = 40;
constexpr uint64_t kTreeOffVoxelCount      = 56;
constexpr uint64_t kTreeSize               = 64;
constexpr uint64_t kMinGridBytes = kGridSize + kTreeSize; // 736
/// NANOVDB_DATA_ALIGNMENT: every node starts 32-byte aligned within the grid
/// and every node size is a multiple of 32. Required, because PNanoVDB's C
/// path reads 64-bit fields (tile keys, child offsets) as aligned 64-bit
/// words: at a misaligned node it would read other bytes than we validated.
constexpr uint64_t kNodeAlignment = 32;

// Row 1 (float) of pnanovdb_grid_type_constants, PNanoVDB 32.4.
constexpr uint32_t kGridTypeFloat = 1;            // PNANOVDB_GRID_TYPE_FLOAT
constexpr uint64_t kRootOffBBoxMin    = 0;        // PNANOVDB_ROOT_OFF_BBOX_MIN
constexpr uint64_t kRootOffBBoxMax    = 12;       // PNANOVDB_ROOT_OFF_BBOX_MAX
constexpr uint64_t kRootOffTableSize  = 24;       // PNANOVDB_ROOT_OFF_TABLE_SIZE
constexpr uint64_t kRootOffBackground = 28;       // root_off_background
constexpr uint64_t kRootSize          = 64;       // root_size
constexpr uint64_t kRootTileOffKey    = 0;        // PNANOVDB_ROOT_TILE_OFF_KEY
constexpr uint64_t kRootTileOffChild  = 8;        // PNANOVDB_ROOT_TILE_OFF_CHILD
constexpr uint64_t kRootTileOffValue  = 20;       // root_tile_off_value
constexpr uint64_t kRootTileSize      = 32;       // root_tile_size
constexpr uint64_t kTableStride       = 8;        // table_stride
constexpr uint64_t kUpperOffChildMask = 4128;     // PNANOVDB_UPPER_OFF_CHILD_MASK
constexpr uint64_t kUpperOffTable     = 8256;     // upper_off_table
constexpr uint64_t kUpperSize         = 270400;   // upper_size
constexpr uint64_t kUpperTableCount   = 32768;    // 32^3
constexpr uint64_t kLowerOffChildMask = 544;      // PNANOVDB_LOWER_OFF_CHILD_MASK
constexpr uint64_t kLowerOffTable     = 1088;     // lower_off_table
constexpr uint64_t kLowerSize         = 33856;    // lower_size
constexpr uint64_t kLowerTableCount   = 4096;     // 16^3
constexpr uint64_t kLeafOffTable      = 96;       // leaf_off_table
constexpr uint64_t kLeafSize          = 2144;     // leaf_size
constexpr uint64_t kLeafValueCount    = 512;      // 8^3

static_assert(kUpperOffTable + kUpperTableCount * kTableStride == kUpperSize);
static_assert(kLowerOffTable + kLowerTableCount * kTableStride == kLowerSize);
static_assert(kLeafOffTable + kLeafValueCount * 4 == kLeafSize);
static_assert(kUpperSize % kNodeAlignment == 0 && kLowerSize % kNodeAlignment == 0 &&
              kLeafSize % kNodeAlignment == 0 && kRootSize % kNodeAlignment == 0 &&
              kRootTileSize % kNodeAlignment == 0);

// ---- Small helpers ------------------------------------------------------------

/// Unaligned little-endian load (the host is assumed little-endian, as every
/// platform Mitsuba supports is).
template <typename T> inline T load(const uint8_t *p) {
    T v;
    std::memcpy(&v, p, sizeof(T));
    return v;
}

inline uint32_t version_major(uint32_t v) { return v >> 21; }

inline std::string version_string(uint32_t v) {
    return std::to_string(v >> 21) + "." + std::to_string((v >> 10) & 0x7ffu) +
           "." + std::to_string(v & 0x3ffu);
}

inline uint64_t byte_swap64(uint64_t v) {
    uint64_t r = 0;
    for (int i = 0; i < 8; ++i)
        r = (r << 8) | ((v >> (8 * i)) & 0xffu);
    return r;
}

inline bool is_byte_swapped_magic(uint64_t m) {
    return m == byte_swap64(kMagicNumb) || m == byte_swap64(kMagicGrid) ||
           m == byte_swap64(kMagicFile);
}

/// "4E 61 6E 6F 56 44 42 30 (\"NanoVDB0\")": hex dump plus printable text.
inline std::string describe_bytes(const uint8_t *p, size_t n) {
    static const char *hex = "0123456789ABCDEF";
    std::string h, t;
    for (size_t i = 0; i < n; ++i) {
        if (i) h += ' ';
        h += hex[p[i] >> 4];
        h += hex[p[i] & 15];
        t += (p[i] >= 0x20 && p[i] < 0x7f) ? char(p[i]) : '.';
    }
    return h + " (\"" + t + "\")";
}

inline std::string describe_magic(uint64_t m) {
    uint8_t b[8];
    std::memcpy(b, &m, 8);
    return describe_bytes(b, 8);
}

inline std::string codec_name(uint16_t c) {
    switch (c) {
        case 0: return "NONE";
        case 1: return "ZIP";
        case 2: return "BLOSC";
        default: return "unknown (" + std::to_string(c) + ")";
    }
}

/// Name stored in a fixed-size, possibly unterminated, character field.
inline std::string fixed_string(const uint8_t *p, size_t n) {
    size_t len = 0;
    while (len < n && p[len] != 0) ++len;
    return std::string(reinterpret_cast<const char *>(p), len);
}

[[noreturn]] inline void fail(const std::string &path, const std::string &msg) {
    throw Error("\"" + path + "\": " + msg);
}

/// Read-only file with bounds-checked positional reads.
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
inline void check_entry_sizes(const std::string &path, const GridEntry &e,
                              const std::string &which) {
    if (e.grid_size < kMinGridBytes)
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

inline std::string entry_label(size_t index, const std::string &name) {
    return "grid " + std::to_string(index) + " \"" + name + "\"";
}

/// Parses consecutive segments starting at byte 0.
inline std::vector<GridEntry> parse_segments(const std::string &path, File &f) {
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
        if (magic != kMagicNumb && magic != kMagicFile)
            fail(path, where + ": expected a NanoVDB segment header (\"NanoVDB0\" or "
                               "\"NanoVDB2\"), found " + describe_magic(magic));
        if (version_major(version) != kMajorVersion)
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
inline bool looks_like_raw_grid(File &f) {
    if (f.size() < kGridSize)
        return false;
    uint8_t g[kGridSize];
    f.read_at(0, g, kGridSize, "grid header");
    const uint64_t magic = load<uint64_t>(g + kGridOffMagic);
    return (magic == kMagicNumb || magic == kMagicGrid) &&
           version_major(load<uint32_t>(g + kGridOffVersion)) == kMajorVersion &&
           load<uint32_t>(g + kGridOffGridType) < 1024 &&
           load<uint32_t>(g + kGridOffGridClass) < 1024;
}

/// Parses a raw grid buffer: grids back to back, each described by its GridData.
inline std::vector<GridEntry> parse_raw(const std::string &path, File &f) {
    std::vector<GridEntry> grids;
    const uint64_t size = f.size();
    uint64_t offset = 0;
    while (offset < size) {
        const size_t index = grids.size();
        const std::string where = "raw grid buffer, grid " + std::to_string(index) +
                                  " (at byte " + std::to_string(offset) + ")";
        if (size - offset < kGridSize)
            fail(path, where + ": truncated grid header: " + std::to_string(size - offset) +
                           " bytes left, a grid header needs 672");
        uint8_t g[kGridSize];
        f.read_at(offset, g, kGridSize, "grid header");
        const uint64_t magic = load<uint64_t>(g + kGridOffMagic);
        const uint32_t version = load<uint32_t>(g + kGridOffVersion);
        if (is_byte_swapped_magic(magic))
            fail(path, where + ": byte-swapped NanoVDB magic " + describe_magic(magic) +
                           ": only little-endian files are supported");
        if (magic != kMagicNumb && magic != kMagicGrid)
            fail(path, where + ": expected a grid magic (\"NanoVDB0\" or \"NanoVDB1\"), found " +
                           describe_magic(magic));
        if (version_major(version) != kMajorVersion)
            fail(path, where + ": NanoVDB grid version " + version_string(version) +
                           " (major " + std::to_string(version_major(version)) +
                           "); only major version 32 is supported");
        GridEntry e;
        e.name        = fixed_string(g + kGridOffName, kGridNameSize);
        e.grid_type   = load<uint32_t>(g + kGridOffGridType);
        e.grid_class  = load<uint32_t>(g + kGridOffGridClass);
        e.grid_size   = load<uint64_t>(g + kGridOffGridSize);
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
inline std::string grid_type_name(uint32_t grid_type) {
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

/// `0: "density" (float), 1: "temperature" (float)`
inline std::string describe_grids(const std::vector<GridEntry> &grids) {
    std::string s;
    for (size_t i = 0; i < grids.size(); ++i) {
        if (i) s += ", ";
        s += std::to_string(i) + ": \"" + grids[i].name + "\" (" +
             grid_type_name(grids[i].grid_type) + ")";
    }
    return s;
}

/// Parses all segment headers and metadata (never the payloads).
inline std::vector<GridEntry> list_grids(const std::string &path) {
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
    if (magic == detail::kMagicGrid) // only ever a grid magic: raw grid buffer
        return detail::parse_raw(path, f);
    if (magic == detail::kMagicFile) // only ever a file magic: segments
        return detail::parse_segments(path, f);
    if (magic != detail::kMagicNumb) {
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
        seg_version_ok = detail::version_major(detail::load<uint32_t>(v)) == detail::kMajorVersion;
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

/// Chooses a grid: empty selector -> first float grid; otherwise a name, or
/// failing that a non-negative decimal index. Only float grids are accepted.
inline const GridEntry &select_grid(const std::string &path,
                                    const std::vector<GridEntry> &grids,
                                    const std::string &selector) {
    if (grids.empty())
        detail::fail(path, "the file holds no grids");
    const GridEntry *chosen = nullptr;
    size_t index = 0;
    if (selector.empty()) {
        for (size_t i = 0; i < grids.size(); ++i)
            if (grids[i].grid_type == detail::kGridTypeFloat) return grids[i];
        detail::fail(path, "no float grid in the file (only float grids are supported); "
                           "the file holds: " + describe_grids(grids));
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
    if (chosen->grid_type != detail::kGridTypeFloat)
        detail::fail(path, detail::entry_label(index, chosen->name) + " has type " +
                               grid_type_name(chosen->grid_type) +
                               ", but only float grids are supported (supported types: float)");
    return *chosen;
}

/// Reads and decodes one grid's payload into `dst` (>= entry.grid_size bytes).
inline void read_grid(const std::string &path, const GridEntry &entry, void *dst) {
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

// ---- Grid level ----------------------------------------------------------------

/// Validates a float grid buffer (only its first grid is used when it holds
/// several) so that the PNanoVDB traversal never leaves it, and summarises it.
/// Every node array is visited once: O(nodes), no recursion, no cycles.
inline FloatGridInfo validate_float_grid(const std::string &path, const void *data,
                                         uint64_t bytes) {
    using namespace detail;
    const uint8_t *buf = static_cast<const uint8_t *>(data);
    if (bytes >= kMaxGridBytes)
        fail(path, "grid buffer of " + std::to_string(bytes) +
                       " bytes is 16 GiB or more: beyond the reader's 32-bit word addresses");
    if (buf == nullptr || bytes < kMinGridBytes)
        fail(path, "grid buffer of " + std::to_string(bytes) +
                       " bytes is too small: a grid needs at least 736 bytes "
                       "(672-byte GridData + 64-byte TreeData)");
    const uint64_t magic = load<uint64_t>(buf + kGridOffMagic);
    if (is_byte_swapped_magic(magic))
        fail(path, "grid has a byte-swapped magic " + describe_magic(magic) +
                       ": only little-endian grids are supported");
    if (magic != kMagicNumb && magic != kMagicGrid)
        fail(path, "not a NanoVDB grid: magic " + describe_magic(magic) +
                       ", expected \"NanoVDB0\" or \"NanoVDB1\"");
    const uint32_t version = load<uint32_t>(buf + kGridOffVersion);
    if (version_major(version) != kMajorVersion)
        fail(path, "grid version " + version_string(version) +
                       "; only major version 32 is supported");
    const uint32_t grid_type = load<uint32_t>(buf + kGridOffGridType);
    const std::string name = fixed_string(buf + kGridOffName, kGridNameSize);
    if (grid_type != kGridTypeFloat)
        fail(path, "grid \"" + name + "\" has type " + grid_type_name(grid_type) +
                       ", but only float grids are supported (supported types: float)");
    const uint64_t end = load<uint64_t>(buf + kGridOffGridSize);
    if (end > bytes)
        fail(path, "GridData.mGridSize = " + std::to_string(end) +
                       " bytes is larger than the " + std::to_string(bytes) + "-byte buffer");
    if (end < kMinGridBytes)
        fail(path, "GridData.mGridSize = " + std::to_string(end) +
                       " bytes is smaller than a grid's 736-byte header");

    const uint64_t tree = kGridSize;
    const uint8_t *t = buf + tree;
    struct Level { const char *name; uint64_t offset, count, node_size, begin; };
    Level leaf  { "leaf",  load<uint64_t>(t + kTreeOffNodeOffsetLeaf),
                  load<uint32_t>(t + kTreeOffNodeCountLeaf),  kLeafSize, 0 };
    Level lower { "lower", load<uint64_t>(t + kTreeOffNodeOffsetLower),
                  load<uint32_t>(t + kTreeOffNodeCountLower), kLowerSize, 0 };
    Level upper { "upper", load<uint64_t>(t + kTreeOffNodeOffsetUpper),
                  load<uint32_t>(t + kTreeOffNodeCountUpper), kUpperSize, 0 };
    for (Level *l : { &leaf, &lower, &upper }) {
        if (l->count == 0)
            continue; // offset unused (writers leave it 0 or point at the end)
        const uint64_t room = end - tree;
        if (l->offset > room || l->count * l->node_size > room - l->offset)
            fail(path, std::string(l->name) + " node array (" + std::to_string(l->count) +
                           " nodes of " + std::to_string(l->node_size) +
                           " bytes at tree offset " + std::to_string(l->offset) +
                           ") does not fit in the " + std::to_string(end) + "-byte grid");
        l->begin = tree + l->offset;
        if (l->begin % kNodeAlignment != 0)
            fail(path, std::string(l->name) + " node array at byte " +
                           std::to_string(l->begin) + " is not 32-byte aligned");
    }

    // Root node and its tile table.
    const uint64_t root_off = load<uint64_t>(t + kTreeOffNodeOffsetRoot);
    if (root_off > end - tree || kRootSize > end - tree - root_off)
        fail(path, "root node offset " + std::to_string(root_off) +
                       " (relative to the tree at byte 672) lies outside the " +
                       std::to_string(end) + "-byte grid");
    const uint64_t root = tree + root_off;
    if (root % kNodeAlignment != 0)
        fail(path, "root node at byte " + std::to_string(root) + " is not 32-byte aligned");
    const uint8_t *r = buf + root;
    const uint64_t table_size = load<uint32_t>(r + kRootOffTableSize);
    if (table_size > (end - root - kRootSize) / kRootTileSize)
        fail(path, "root tile table of " + std::to_string(table_size) +
                       " tiles (table_size; root at byte " + std::to_string(root) +
                       ") extends past the end of the " + std::to_string(end) + "-byte grid");

    // The header, the root with its tile table and the three node arrays are
    // disjoint (NanoVDB writes them back to back). Were they allowed to
    // overlap, one node's bytes would also be read as a node of another level
    // or as the root: a child offset could then point at its own parent, or a
    // leaf's values be read as child offsets. Lookups could not leave the
    // buffer even so (every node a child offset reaches is checked below),
    // but no writer produces such a grid, so it is reported as corrupt.
    {
        struct Region { const char *name; uint64_t begin, end; };
        const Region regions[] = {
            { "grid and tree header", 0, kMinGridBytes },
            { "root node and its tile table", root, root + kRootSize + table_size * kRootTileSize },
            { "upper node array", upper.begin, upper.begin + upper.count * kUpperSize },
            { "lower node array", lower.begin, lower.begin + lower.count * kLowerSize },
            { "leaf node array", leaf.begin, leaf.begin + leaf.count * kLeafSize },
        };
        auto span = [](const Region &x) {
            return "[" + std::to_string(x.begin) + ", " + std::to_string(x.end) + ")";
        };
        for (size_t a = 0; a < 5; ++a)
            for (size_t b = a + 1; b < 5; ++b) {
                const Region &x = regions[a], &y = regions[b];
                if (x.begin == x.end || y.begin == y.end)
                    continue; // a level without nodes occupies nothing
                if (x.begin < y.end && y.begin < x.end)
                    fail(path, std::string("the ") + y.name + " " + span(y) + " overlaps the " +
                                   x.name + " " + span(x));
            }
    }

    FloatGridInfo info{};
    info.root_word = uint32_t(root / 4);
    for (int i = 0; i < 3; ++i) {
        info.bbox_min[i] = load<int32_t>(r + kRootOffBBoxMin + 4 * i);
        info.bbox_max[i] = load<int32_t>(r + kRootOffBBoxMax + 4 * i);
    }
    info.empty = info.bbox_min[0] > info.bbox_max[0] || info.bbox_min[1] > info.bbox_max[1] ||
                 info.bbox_min[2] > info.bbox_max[2];
    info.background = load<float>(r + kRootOffBackground);

    float vmin = std::numeric_limits<float>::infinity();
    float vmax = -std::numeric_limits<float>::infinity();
    uint64_t nan_count = 0, inf_count = 0, finite_or_inf = 0;
    auto account = [&](float v) {
        if (std::isnan(v)) { ++nan_count; return; }
        if (std::isinf(v)) ++inf_count;
        ++finite_or_inf;
        vmin = std::min(vmin, v);
        vmax = std::max(vmax, v);
    };
    account(info.background);

    // `child` (relative to `from`) must point exactly at a node of `level`.
    // `who` is a callable returning the parent's description: built only for
    // a message (millions of children are checked in a large grid).
    auto check_child = [&](const Level &level, uint64_t from, int64_t child,
                           const auto &who) {
        const uint64_t array_end = level.begin + level.count * level.node_size;
        if (level.count != 0 && child >= -int64_t(end) && child <= int64_t(end)) {
            const int64_t t = int64_t(from) + child; // |from|, |child| <= 2^34: no overflow
            if (t >= int64_t(level.begin) && uint64_t(t) < array_end &&
                (uint64_t(t) - level.begin) % level.node_size == 0)
                return; // the common case, without building any message
        }
        const std::string msg_head = who() + " has child offset " + std::to_string(child);
        if (level.count == 0)
            fail(path, msg_head + ", but the grid has no " + level.name + " nodes");
        // Signed range check without overflow: target = from + child.
        if ((child < 0 && uint64_t(-(child + 1)) + 1 > from) ||
            (child >= 0 && uint64_t(child) > end - from))
            fail(path, msg_head + ": outside the " + std::to_string(end) + "-byte grid");
        const uint64_t target = child < 0 ? from - (uint64_t(-(child + 1)) + 1)
                                          : from + uint64_t(child);
        if (target < level.begin || target >= array_end)
            fail(path, msg_head + " (byte " + std::to_string(target) + "): outside the " +
                           level.name + " node array [" + std::to_string(level.begin) + ", " +
                           std::to_string(array_end) + ")");
        if ((target - level.begin) % level.node_size != 0)
            fail(path, msg_head + " (byte " + std::to_string(target) + "): misaligned, not at a " +
                           level.name + " node boundary (array at byte " +
                           std::to_string(level.begin) + ", stride " +
                           std::to_string(level.node_size) + ")");
    };

    // Root tiles: PNanoVDB follows a non-zero child, else reads the tile value.
    for (uint64_t i = 0; i < table_size; ++i) {
        const uint8_t *tile = r + kRootSize + i * kRootTileSize;
        const int64_t child = load<int64_t>(tile + kRootTileOffChild);
        if (child == 0) {
            account(load<float>(tile + kRootTileOffValue));
        } else {
            check_child(upper, root, child, [&] {
                return "root tile " + std::to_string(i) + " (key " +
                       std::to_string(load<uint64_t>(tile + kRootTileOffKey)) + ")";
            });
        }
    }

    // Internal nodes: each child-mask bit selects a child offset (relative to
    // the node) or, when clear, a tile value in the same 8-byte table entry.
    auto scan_internal = [&](const Level &level, const Level &child_level, uint64_t mask_off,
                             uint64_t table_off, uint64_t table_count) {
        for (uint64_t n = 0; n < level.count; ++n) {
            const uint64_t node = level.begin + n * level.node_size;
            const uint8_t *p = buf + node;
            for (uint64_t w = 0; w < table_count / 32; ++w) {
                const uint32_t mask = load<uint32_t>(p + mask_off + 4 * w);
                for (uint64_t b = 0; b < 32; ++b) {
                    const uint64_t k = w * 32 + b;
                    const uint8_t *entry = p + table_off + k * kTableStride;
                    if (mask & (uint32_t(1) << b))
                        check_child(child_level, node, load<int64_t>(entry), [&] {
                            return std::string(level.name) + " node " + std::to_string(n) +
                                   " (byte " + std::to_string(node) + ") table entry " +
                                   std::to_string(k);
                        });
                    else
                        account(load<float>(entry));
                }
            }
        }
    };
    scan_internal(upper, lower, kUpperOffChildMask, kUpperOffTable, kUpperTableCount);
    scan_internal(lower, leaf, kLowerOffChildMask, kLowerOffTable, kLowerTableCount);

    // Leaves hold almost all values: a branch-free pass per leaf (min/max
    // and a count of NaN/Inf bit patterns, which the compiler vectorizes),
    // and the per-value accounting only for a leaf holding NaN or Inf.
    // (4.6 GiB grid: ~12 s -> ~1 s.)
    for (uint64_t n = 0; n < leaf.count; ++n) {
        const uint8_t *p = buf + leaf.begin + n * kLeafSize + kLeafOffTable;
        float values[kLeafValueCount];
        std::memcpy(values, p, sizeof(values));
        float lmin = std::numeric_limits<float>::infinity(), lmax = -lmin;
        uint32_t special = 0;
        for (uint64_t k = 0; k < kLeafValueCount; ++k) {
            uint32_t bits;
            std::memcpy(&bits, &values[k], 4);
            special += (bits & 0x7f800000u) == 0x7f800000u ? 1u : 0u;
            lmin = values[k] < lmin ? values[k] : lmin;
            lmax = values[k] > lmax ? values[k] : lmax;
        }
        if (special == 0) {
            finite_or_inf += kLeafValueCount;
            vmin = std::min(vmin, lmin);
            vmax = std::max(vmax, lmax);
        } else {
            for (uint64_t k = 0; k < kLeafValueCount; ++k)
                account(values[k]);
        }
    }

    if (finite_or_inf == 0)
        vmin = vmax = std::numeric_limits<float>::quiet_NaN();
    info.value_min = vmin;
    info.value_max = vmax;
    info.nan_count = nan_count;
    info.inf_count = inf_count;
    for (int i = 0; i < 9; ++i) {
        info.map_mat[i] = load<double>(buf + kGridOffMap + kMapOffMatD + 8 * i);
        info.map_inv[i] = load<double>(buf + kGridOffMap + kMapOffInvMatD + 8 * i);
    }
    for (int i = 0; i < 3; ++i) {
        info.map_vec[i]    = load<double>(buf + kGridOffMap + kMapOffVecD + 8 * i);
        info.voxel_size[i] = load<double>(buf + kGridOffVoxelSize + 8 * i);
    }
    info.grid_class = load<uint32_t>(buf + kGridOffGridClass);
    info.name = name;
    info.node_count[0] = uint32_t(leaf.count);
    info.node_count[1] = uint32_t(lower.count);
    info.node_count[2] = uint32_t(upper.count);
    info.active_voxel_count = load<uint64_t>(t + kTreeOffVoxelCount);
    return info;
}


// ---- Values: NaN, infinities, negatives ---------------------------------------------
//
// Policy support for the plugin (which decides what to do with the counts):
// scan_values() finds NaN, +-Inf and negative values and the index coordinate
// of the first of each; sanitize_values() replaces them in place.
//
// Which values: exactly the set that validate_float_grid() summarises in
// value_min / value_max / nan_count / inf_count -- the background, root tiles
// without child, upper/lower table entries whose child bit is 0, and all 512
// values of every leaf (active or not). That is every value a lookup can
// return, plus values in nodes that no root tile reaches (a lookup never
// returns those, but they bound max(), so they are scanned and sanitized too).
//
// Order ("first"): background, root tiles in table order, upper nodes, lower
// nodes, leaves, each in array order, entries in table order: the order of
// the bytes in a NanoVDB-written buffer.
//
// Coordinates are those a lookup uses, found by walking the tree from the root
// tiles' keys (never from the nodes' stored bounding boxes, which lookups do
// not read): a voxel for a leaf value; for a tile, the first (minimum) voxel
// of the 8^3 (lower), 128^3 (upper) or 4096^3 (root) block it covers. A node
// reached by no root tile gets the origin stored in its own bbox (rounded
// down to the node size) and is flagged unreachable.

/// Where a value sits: its level (PNanoVDB's codes) and index coordinate.
struct ValueLocation {
    /// 0 leaf voxel, 1 lower-node tile (8^3 voxels), 2 upper-node tile
    /// (128^3), 3 root tile (4096^3), 4 the background (no coordinate).
    uint32_t level = 4;
    int32_t  ijk[3] = { 0, 0, 0 }; ///< voxel, or the tile's minimum voxel
    uint64_t byte = 0;             ///< byte offset of the value in the grid buffer
    bool     reachable = true;     ///< false: in a node that no root tile reaches
};

/// "voxel (1, -2, 3)", "lower-node tile (8^3 voxels) at (8, 0, 0)",
/// "upper-node tile (128^3 voxels) at ...", "root tile (4096^3 voxels) at
/// ...", "background"; unreachable nodes add ", in a node no root tile reaches".
inline std::string describe_location(const ValueLocation &l) {
    if (l.level >= 4)
        return "background";
    static const char *what[] = { "voxel", "lower-node tile (8^3 voxels) at",
                                  "upper-node tile (128^3 voxels) at",
                                  "root tile (4096^3 voxels) at" };
    std::string s = std::string(what[l.level]) + " (" + std::to_string(l.ijk[0]) + ", " +
                    std::to_string(l.ijk[1]) + ", " + std::to_string(l.ijk[2]) + ")";
    if (!l.reachable)
        s += ", in a node no root tile reaches";
    return s;
}

/// Result of scan_values().
struct ValueScan {
    uint64_t value_count = 0;    ///< values examined (see "Which values" above)
    uint64_t nan_count = 0;      ///< NaN (any payload, either sign)
    uint64_t posinf_count = 0;   ///< +Inf
    uint64_t neginf_count = 0;   ///< -Inf
    uint64_t negative_count = 0; ///< finite and < 0 (-0.0 is not negative; -Inf is not counted here)
    bool has_nan = false, has_inf = false, has_negative = false;
    ValueLocation first_nan, first_inf, first_negative; ///< valid where has_*
    /// Largest finite value (-Inf if there is none): what sanitize_values()
    /// puts in place of +Inf.
    float finite_max = -std::numeric_limits<float>::infinity();
};

namespace detail {

/// Visits every value of a validated grid (see "Which values" above) in
/// buffer order: f(float *value, const ValueLocation &). `value` may be
/// unaligned (read and write it with memcpy). `buf` must have passed
/// validate_float_grid(), which produced `info`.
template <typename F>
void for_each_value(uint8_t *buf, const FloatGridInfo &info, F &&f) {
    const uint8_t *t = buf + kGridSize;
    const uint64_t root = uint64_t(info.root_word) * 4;
    uint8_t *r = buf + root;
    const uint64_t table_size = load<uint32_t>(r + kRootOffTableSize);
    const uint64_t begin[3] = { kGridSize + load<uint64_t>(t + kTreeOffNodeOffsetLeaf),
                                kGridSize + load<uint64_t>(t + kTreeOffNodeOffsetLower),
                                kGridSize + load<uint64_t>(t + kTreeOffNodeOffsetUpper) };
    const uint64_t count[3] = { info.node_count[0], info.node_count[1], info.node_count[2] };
    const uint64_t size[3] = { kLeafSize, kLowerSize, kUpperSize };

    // Origins of the nodes, from the root keys down (first path wins).
    struct Origin { int32_t ijk[3]; bool set; };
    std::vector<Origin> origin[3];
    for (int l = 0; l < 3; ++l)
        origin[l].assign(size_t(count[l]), Origin{ { 0, 0, 0 }, false });
    auto child_index = [&](int level, uint64_t parent, int64_t delta) {
        const uint64_t target = uint64_t(int64_t(parent) + delta); // validated
        return size_t((target - begin[level]) / size[level]);
    };
    // Internal node entry n -> offset of its child block; log2 of dims
    auto decode = [](uint64_t n, int log2dim, int log2child, const int32_t *o, int32_t *out) {
        const uint64_t mask = (uint64_t(1) << log2dim) - 1;
        const uint64_t i = n >> (2 * log2dim), j = (n >> log2dim) & mask, k = n & mask;
        out[0] = int32_t(uint32_t(o[0]) + (uint32_t(i) << log2child));
        out[1] = int32_t(uint32_t(o[1]) + (uint32_t(j) << log2child));
        out[2] = int32_t(uint32_t(o[2]) + (uint32_t(k) << log2child));
    };
    auto key_origin = [](uint64_t key, int32_t *out) {
        out[0] = int32_t(uint32_t((key >> 42) & 0x1fffffu) << 12);
        out[1] = int32_t(uint32_t((key >> 21) & 0x1fffffu) << 12);
        out[2] = int32_t(uint32_t(key & 0x1fffffu) << 12);
    };
    for (uint64_t i = 0; i < table_size; ++i) {
        const uint8_t *tile = r + kRootSize + i * kRootTileSize;
        const int64_t child = load<int64_t>(tile + kRootTileOffChild);
        if (child == 0) continue;
        Origin &o = origin[2][child_index(2, root, child)];
        if (o.set) continue;
        key_origin(load<uint64_t>(tile + kRootTileOffKey), o.ijk);
        o.set = true;
    }
    struct Internal { int level; uint64_t mask_off, table_off, count; int log2dim, log2child; };
    const Internal internal[2] = { { 2, kUpperOffChildMask, kUpperOffTable, kUpperTableCount, 5, 7 },
                                   { 1, kLowerOffChildMask, kLowerOffTable, kLowerTableCount, 4, 3 } };
    for (const Internal &in : internal) {
        const int below = in.level - 1;
        for (uint64_t n = 0; n < count[in.level]; ++n) {
            const Origin &o = origin[in.level][size_t(n)];
            if (!o.set) continue; // unreachable: its children keep no origin from it
            const uint64_t node = begin[in.level] + n * size[in.level];
            for (uint64_t e = 0; e < in.count; ++e) {
                if (!((load<uint32_t>(buf + node + in.mask_off + 4 * (e >> 5)) >> (e & 31)) & 1u))
                    continue;
                Origin &c = origin[below][child_index(below, node,
                    load<int64_t>(buf + node + in.table_off + e * kTableStride))];
                if (c.set) continue;
                decode(e, in.log2dim, in.log2child, o.ijk, c.ijk);
                c.set = true;
            }
        }
    }
    auto node_origin = [&](int level, uint64_t n, ValueLocation &loc) {
        const Origin &o = origin[level][size_t(n)];
        if (o.set) {
            std::memcpy(loc.ijk, o.ijk, sizeof(loc.ijk));
            loc.reachable = true;
        } else { // the node's own bbox minimum, rounded down to the node size
            const uint8_t *p = buf + begin[level] + n * size[level];
            const uint32_t m = level == 0 ? 7u : level == 1 ? 127u : 4095u;
            for (int k = 0; k < 3; ++k)
                loc.ijk[k] = int32_t(load<uint32_t>(p + 4 * k) & ~m);
            loc.reachable = false;
        }
    };

    ValueLocation loc;
    loc.level = 4;
    loc.byte = root + kRootOffBackground;
    f(reinterpret_cast<float *>(buf + loc.byte), loc);
    for (uint64_t i = 0; i < table_size; ++i) {
        const uint8_t *tile = r + kRootSize + i * kRootTileSize;
        if (load<int64_t>(tile + kRootTileOffChild) != 0) continue;
        loc.level = 3;
        loc.reachable = true;
        key_origin(load<uint64_t>(tile + kRootTileOffKey), loc.ijk);
        loc.byte = uint64_t(tile - buf) + kRootTileOffValue;
        f(reinterpret_cast<float *>(buf + loc.byte), loc);
    }
    for (const Internal &in : internal) {
        for (uint64_t n = 0; n < count[in.level]; ++n) {
            const uint64_t node = begin[in.level] + n * size[in.level];
            ValueLocation base;
            node_origin(in.level, n, base);
            for (uint64_t e = 0; e < in.count; ++e) {
                if ((load<uint32_t>(buf + node + in.mask_off + 4 * (e >> 5)) >> (e & 31)) & 1u)
                    continue;
                loc = base;
                loc.level = uint32_t(in.level);
                decode(e, in.log2dim, in.log2child, base.ijk, loc.ijk);
                loc.byte = node + in.table_off + e * kTableStride;
                f(reinterpret_cast<float *>(buf + loc.byte), loc);
            }
        }
    }
    for (uint64_t n = 0; n < count[0]; ++n) {
        const uint64_t node = begin[0] + n * kLeafSize;
        ValueLocation base;
        node_origin(0, n, base);
        for (uint64_t e = 0; e < kLeafValueCount; ++e) {
            loc = base;
            loc.level = 0;
            decode(e, 3, 0, base.ijk, loc.ijk);
            loc.byte = node + kLeafOffTable + 4 * e;
            f(reinterpret_cast<float *>(buf + loc.byte), loc);
        }
    }
}

} // namespace detail

/// Counts NaN, +-Inf and negative values of a float grid buffer and locates
/// the first of each (see "Which values", "Order" and "Coordinates" above).
/// Validates the buffer first (validate_float_grid(): same errors). Does not
/// modify the buffer. O(values), plus one pass over the internal nodes.
inline ValueScan scan_values(const std::string &path, const void *data, uint64_t bytes) {
    const FloatGridInfo info = validate_float_grid(path, data, bytes);
    ValueScan s;
    // for_each_value hands out mutable pointers; nothing is written here.
    detail::for_each_value(const_cast<uint8_t *>(static_cast<const uint8_t *>(data)), info,
                           [&](float *p, const ValueLocation &loc) {
        float v;
        std::memcpy(&v, p, sizeof(float));
        ++s.value_count;
        if (std::isnan(v)) {
            if (!s.has_nan) { s.has_nan = true; s.first_nan = loc; }
            ++s.nan_count;
        } else if (std::isinf(v)) {
            if (!s.has_inf) { s.has_inf = true; s.first_inf = loc; }
            ++(v > 0 ? s.posinf_count : s.neginf_count);
        } else {
            s.finite_max = std::max(s.finite_max, v);
            if (v < 0.f) {
                if (!s.has_negative) { s.has_negative = true; s.first_negative = loc; }
                ++s.negative_count;
            }
        }
    });
    return s;
}

/// "3 NaN (first: voxel (1, 2, 3)), 1 +Inf and 0 -Inf values (first
/// infinite: background)": the part of a load error that scan_values() fills.
inline std::string describe_invalid_values(const ValueScan &s) {
    std::string msg = std::to_string(s.nan_count) + " NaN";
    if (s.has_nan) msg += " (first: " + describe_location(s.first_nan) + ")";
    msg += ", " + std::to_string(s.posinf_count) + " +Inf and " +
           std::to_string(s.neginf_count) + " -Inf values";
    if (s.has_inf) msg += " (first infinite: " + describe_location(s.first_inf) + ")";
    return msg;
}

/// What sanitize_values() does with each kind of value.
struct SanitizeOptions {
    /// Replace finite negative values (and -Inf) by 0. Without it, negatives
    /// are kept and -Inf becomes the lowest finite value of the grid.
    bool clamp_negative = true;
};

/// Counts of the replacements made by sanitize_values().
struct SanitizeResult {
    uint64_t nan = 0, posinf = 0, neginf = 0, negative = 0;
    uint64_t total() const { return nan + posinf + neginf + negative; }
};

/// Replaces invalid values in place (every value scan_values() examines):
///   NaN       -> 0 (no medium: the neutral density);
///   +Inf      -> the largest finite value of the grid (0 if there is none).
///                Not FLT_MAX: the medium's majorant is scale * max(), and a
///                majorant near FLT_MAX makes delta tracking take steps of
///                1e-38 (it never leaves the volume) or overflows to Inf;
///   -Inf      -> 0 with clamp_negative, else the lowest finite value;
///   negative  -> 0 with clamp_negative (a density cannot be negative; a
///                negative majorant breaks tracking), else kept.
/// Validates first (same errors as validate_float_grid()). Call
/// validate_float_grid() again afterwards for the new value_min/value_max.
inline SanitizeResult sanitize_values(const std::string &path, void *data, uint64_t bytes,
                                      const SanitizeOptions &options = {}) {
    const FloatGridInfo info = validate_float_grid(path, data, bytes);
    uint8_t *buf = static_cast<uint8_t *>(data);
    float finite_max = -std::numeric_limits<float>::infinity();
    float finite_min = std::numeric_limits<float>::infinity();
    detail::for_each_value(buf, info, [&](float *p, const ValueLocation &) {
        float v;
        std::memcpy(&v, p, sizeof(float));
        if (std::isfinite(v)) {
            finite_max = std::max(finite_max, v);
            finite_min = std::min(finite_min, v);
        }
    });
    const bool any_finite = finite_max >= finite_min;
    // With clamp_negative every negative becomes 0, so the largest value left
    // is at least 0.
    const float pos_repl = !any_finite ? 0.f
                         : options.clamp_negative ? std::max(finite_max, 0.f) : finite_max;
    const float neg_repl = options.clamp_negative || !any_finite ? 0.f : finite_min;
    SanitizeResult r;
    detail::for_each_value(buf, info, [&](float *p, const ValueLocation &) {
        float v;
        std::memcpy(&v, p, sizeof(float));
        float w = v;
        if (std::isnan(v)) { w = 0.f; ++r.nan; }
        else if (v == std::numeric_limits<float>::infinity()) { w = pos_repl; ++r.posinf; }
        else if (v == -std::numeric_limits<float>::infinity()) { w = neg_repl; ++r.neginf; }
        else if (v < 0.f && options.clamp_negative) { w = 0.f; ++r.negative; }
        else return;
        std::memcpy(p, &w, sizeof(float));
    });
    return r;
}

} // namespace nanovdb_drjit::io
