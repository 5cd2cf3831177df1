// OpenVDB's two chunk readers, io::bloscFromStream and io::unzipFromStream,
// replaced in the processes that read .vdb files (nanovdb-vdb-reader,
// vdb2nvdb and the .vdb fuzzer; never a plugin) by ones that check a
// chunk's sizes before they write or read a byte (vdb_chunks.h).
//
// Why. A .vdb stores each node's voxel values as a chunk: an int64 count,
// then that many bytes, blosc- or zlib-compressed, or stored as they are
// when the count is negative. OpenVDB 10 (io/Compression.cc) trusts the
// count:
//  * a stored chunk is read whole into the caller's buffer, whose size is
//    compared with the count only afterwards: a damaged count writes past
//    the buffer. In the fuzz campaign (tests/fuzz/CAMPAIGN.md) this was
//    1,750 of the first 1,950 findings, all in bloscFromStream;
//  * a blosc chunk is handed to blosc_decompress_ctx, which takes no source
//    size and reads as many bytes as the chunk's own header says, past the
//    end of a shorter chunk (blosc_decompress_ctx, LZ4_decompress_safe: 23
//    findings).
// The reader process contains those crashes (vdb_import.cpp), but the user
// then learns only that OpenVDB crashed, and each crash costs the fuzzer a
// restart. Here a damaged chunk is an exception with what is wrong, which
// vdb_read.cpp reports with the file's name.
//
// How. Both functions are exported by libopenvdb and called through its
// PLT, so a definition in the executable takes their place for every
// caller in the process (ELF interposition, the mechanism by which
// vdb_reader_budget.cpp replaces operator new). The executables export the
// two (GNU ld does for a symbol that a linked library defines too, and
// CMakeLists.txt asks for them by name), and chunk_readers_replaced() says
// whether the dynamic linker chose them (test_vdb_chunks checks it; should
// a future OpenVDB bind its calls directly, the reader's process still
// contains the crash).
//
// The contract is OpenVDB's (io/Compression.h documents the two
// functions): for a well-formed chunk the same bytes land in `data`, and
// with data == nullptr the chunk is skipped. Written from that contract and
// blosc's and zlib's documented APIs; a doctest (test_io's vdb_chunks)
// compares the two with OpenVDB's own on well-formed and damaged chunks.

#include "vdb_chunks.h"

#include <openvdb/Exceptions.h>
#include <openvdb/io/Compression.h>

#include <blosc.h>
#include <dlfcn.h>
#include <zlib.h>

#include <cstdint>
#include <cstring>
#include <istream>
#include <memory>
#include <string>

namespace {

using Int64 = int64_t;

[[noreturn]] void damaged(const std::string &what) {
    OPENVDB_THROW(openvdb::IoError, "damaged voxel data: " + what);
}

std::string bytes(uint64_t n) {
    return std::to_string(n) + (n == 1 ? " byte" : " bytes");
}

/// The chunk's int64 count (stream failures: a truncated file)
Int64 read_count(std::istream &is, const char *codec) {
    Int64 n = 0;
    is.read(reinterpret_cast<char *>(&n), sizeof n);
    if (!is || is.gcount() != std::streamsize(sizeof n))
        damaged(std::string("the file ends inside a ") + codec + " chunk's size");
    return n;
}

/// Reads (or skips, data == nullptr) `n` bytes, failing on a short read
void read_exactly(std::istream &is, char *data, uint64_t n, const char *codec) {
    if (data == nullptr) {
        is.seekg(std::streamoff(n), std::ios_base::cur);
        if (!is)
            damaged(std::string("a ") + codec + " chunk of " + bytes(n) +
                    " runs past the end of the file");
        return;
    }
    is.read(data, std::streamsize(n));
    if (!is || uint64_t(is.gcount()) != n)
        damaged(std::string("a ") + codec + " chunk of " + bytes(n) + " is cut short at " +
                bytes(uint64_t(is.gcount())) + " (a truncated file?)");
}

/**
 * A chunk stored as it is (count <= 0: -count bytes). Its size must be the
 * buffer's, checked before anything is read into the buffer.
 */
void read_stored(std::istream &is, char *data, size_t numBytes, Int64 n, const char *codec) {
    if (n == INT64_MIN || uint64_t(-n) != uint64_t(numBytes))
        damaged(std::string("an uncompressed ") + codec + " chunk declares " +
                (n == INT64_MIN ? std::string("-2^63 bytes") : bytes(uint64_t(-n))) +
                " where the node holds " + bytes(numBytes));
    read_exactly(is, data, numBytes, codec);
}

/// A compressed chunk's bytes, read whole into a buffer of their own
/// (under the reader's memory budget), after a bound on their count
std::unique_ptr<char[]> read_compressed(std::istream &is, uint64_t n, uint64_t bound,
                                        size_t numBytes, const char *codec) {
    if (n > bound)
        damaged(std::string("a ") + codec + " chunk declares " + bytes(n) +
                " of compressed data for a node of " + bytes(numBytes) + " (at most " +
                bytes(bound) + " can be valid)");
    std::unique_ptr<char[]> buf(new char[n]);
    read_exactly(is, buf.get(), n, codec);
    return buf;
}

/**
 * A chunk's start: its count, and a stored chunk (or any chunk skipped,
 * data == nullptr) read whole. Returns the byte count of a compressed
 * chunk still to read into `data`, or 0 once the chunk is done.
 */
uint64_t begin_chunk(std::istream &is, char *data, size_t numBytes, const char *codec) {
    const Int64 n = read_count(is, codec);
    if (n <= 0)
        read_stored(is, data, numBytes, n, codec);
    else if (data == nullptr)
        read_exactly(is, nullptr, uint64_t(n), codec);
    else
        return uint64_t(n);
    return 0;
}

} // namespace

namespace openvdb {
OPENVDB_USE_VERSION_NAMESPACE
namespace OPENVDB_VERSION_NAME {
namespace io {

void bloscFromStream(std::istream &is, char *data, size_t numBytes) {
    const uint64_t n = begin_chunk(is, data, numBytes, "blosc");
    if (n == 0)
        return;
    // blosc never makes more than its header over the input (it stores a
    // block that does not compress), and OpenVDB writes what it made
    std::unique_ptr<char[]> src =
        read_compressed(is, n, uint64_t(numBytes) + BLOSC_MAX_OVERHEAD, numBytes, "blosc");
    // The chunk's own header (sizes, block starts) checked against the bytes
    // that are there, before blosc reads as many as it says
    size_t declared = 0;
    if (blosc_cbuffer_validate(src.get(), size_t(n), &declared) != 0)
        damaged("a blosc chunk of " + bytes(n) + " has a corrupt header");
    if (declared != numBytes)
        damaged("a blosc chunk decompresses to " + bytes(declared) + " where the node holds " +
                bytes(numBytes));
    const int got = blosc_decompress_ctx(src.get(), data, numBytes, /*numinternalthreads=*/1);
    if (got < 0 || size_t(got) != numBytes)
        damaged("a blosc chunk of " + bytes(n) + " does not decompress (" +
                (got < 0 ? "corrupt data" : "it gives " + bytes(uint64_t(got))) +
                ", where the node holds " + bytes(numBytes) + ")");
}

void unzipFromStream(std::istream &is, char *data, size_t numBytes) {
    const uint64_t n = begin_chunk(is, data, numBytes, "zip");
    if (n == 0)
        return;
    std::unique_ptr<char[]> src =
        read_compressed(is, n, compressBound(uLong(numBytes)), numBytes, "zip");
    uLongf got = uLongf(numBytes);
    const int status = uncompress(reinterpret_cast<Bytef *>(data), &got,
                                  reinterpret_cast<const Bytef *>(src.get()), uLong(n));
    if (status != Z_OK || got != numBytes)
        damaged("a zip chunk of " + bytes(n) + " does not decompress (" +
                (status != Z_OK ? std::string("zlib: ") + zError(status)
                                : "it gives " + bytes(uint64_t(got))) +
                ", where the node holds " + bytes(numBytes) + ")");
}

} // namespace io
} // namespace OPENVDB_VERSION_NAME
} // namespace openvdb

namespace nanovdb_loader::vdb_reader {

/*
 * A delayed-load value, as OpenVDB 10 writes it (io/DelayedLoadMetadata.cc):
 *   uint32 count
 *   uint32 b, then a mask of count int8: blosc-compressed in b bytes (b > 0)
 *     or stored (b = 0: count bytes)
 *   uint32 c, then count int64 chunk sizes: none (c = 0xffffffff),
 *     blosc-compressed in c bytes (0 < c < 0xffffffff) or stored (c = 0)
 * (an array of fewer than 128 bytes is padded to 128 before compression).
 * The reader takes blosc's header for the uncompressed size and reads the
 * b or c bytes without checking them against the value's size.
 */
std::string delayed_load_damage(const char *value, size_t size) {
    if (size == 0)
        return ""; // (an empty value: OpenVDB reads nothing)
    size_t at = 0;
    auto u32 = [&](uint32_t &v) {
        if (size - at < 4)
            return false;
        std::memcpy(&v, value + at, 4);
        at += 4;
        return true;
    };
    uint32_t count = 0, b = 0, c = 0;
    if (!u32(count) || !u32(b))
        return "a delayed-load value of " + bytes(size) + " is too short for its header";
    // One array: blosc-compressed in n bytes, or stored (n = 0)
    auto array = [&](uint32_t n, uint64_t entry, const char *name) -> std::string {
        const uint64_t want = uint64_t(count) * entry;
        if (n == 0) {
            if (want > size - at)
                return std::string("its stored ") + name + " of " + bytes(want) + " exceeds the " +
                       bytes(size - at) + " left in the value";
            at += size_t(want);
            return "";
        }
        if (n > size - at)
            return std::string("its compressed ") + name + " of " + bytes(n) + " exceeds the " +
                   bytes(size - at) + " left in the value";
        size_t declared = 0;
        if (blosc_cbuffer_validate(value + at, n, &declared) != 0)
            return std::string("its compressed ") + name + " has a corrupt blosc header";
        // (OpenVDB's writer pads an array of fewer than 128 bytes to 128
        // before compressing it, and its reader accepts that)
        constexpr uint64_t kPadBytes = 128;
        if (declared != want && !(declared == kPadBytes && want <= kPadBytes))
            return std::string("its compressed ") + name + " decompresses to " + bytes(declared) +
                   ", not the " + bytes(want) + " of " + std::to_string(count) + " entries";
        at += n;
        return "";
    };
    std::string bad = array(b, 1, "mask");
    if (bad.empty()) {
        if (!u32(c))
            return "a delayed-load value of " + bytes(size) + " ends before its chunk sizes";
        if (c != UINT32_MAX)
            bad = array(c, 8, "chunk sizes");
    }
    return bad.empty() ? "" : "a delayed-load value of " + bytes(size) + ": " + bad;
}

namespace {

/// Whether the process's global scope binds the exported name of the
/// function at `ours` (its mangled name, as this executable exports it) to
/// `ours`, where libopenvdb's calls then go
bool bound_here(void *ours) {
    Dl_info info{};
    if (!dladdr(ours, &info) || !info.dli_sname || info.dli_saddr != ours)
        return false; // not exported: libopenvdb keeps its own
    return dlsym(RTLD_DEFAULT, info.dli_sname) == ours;
}

} // namespace

bool chunk_readers_replaced() {
    return bound_here(reinterpret_cast<void *>(&openvdb::io::bloscFromStream)) &&
           bound_here(reinterpret_cast<void *>(&openvdb::io::unzipFromStream));
}

} // namespace nanovdb_loader::vdb_reader
