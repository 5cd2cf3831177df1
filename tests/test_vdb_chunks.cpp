// The checked chunk readers (src/loader/vdb_chunks.cpp) against OpenVDB's
// own, which this process still reaches by name past its own definitions
// (dlsym RTLD_NEXT): on well-formed chunks that OpenVDB's writers make
// (blosc, zip and stored; many sizes and contents), the same bytes land in
// the buffer and the stream stops at the same place; with data == nullptr
// both skip the same bytes. On damaged chunks, ours throws where OpenVDB's
// would write or read out of bounds, with what is wrong.

#include <doctest/doctest.h>

#include "../src/loader/vdb_chunks.h"

#include <openvdb/Exceptions.h>
#include <openvdb/io/Compression.h>

#include <dlfcn.h>

#include <cstdint>
#include <cstring>
#include <random>
#include <sstream>
#include <string>
#include <vector>

namespace {

using Reader = void (*)(std::istream &, char *, size_t);

/// OpenVDB's definition of the function at `ours` (the next one in the
/// lookup order after this executable's)
Reader upstream(void *ours) {
    Dl_info info{};
    REQUIRE(dladdr(ours, &info) != 0);
    REQUIRE(info.dli_sname != nullptr);
    void *next = dlsym(RTLD_NEXT, info.dli_sname);
    REQUIRE(next != nullptr);
    REQUIRE(next != ours);
    return reinterpret_cast<Reader>(next);
}

Reader ours_blosc() { return &openvdb::io::bloscFromStream; }
Reader ours_zip() { return &openvdb::io::unzipFromStream; }

/// Values as a node holds them: smooth (compressible), noise, constant
std::vector<char> values(size_t n, int kind, uint32_t seed) {
    std::vector<char> v(n);
    std::mt19937 rng(seed);
    for (size_t i = 0; i < n; ++i) {
        if (kind == 0)
            v[i] = char((i / 7) & 0xff);
        else if (kind == 1)
            v[i] = char(rng() & 0xff);
        else
            v[i] = 42;
    }
    return v;
}

/// A stream holding one chunk written by OpenVDB's writer, then a sentinel
std::string chunk(const std::vector<char> &v, bool blosc) {
    std::ostringstream os(std::ios_base::binary);
    if (blosc)
        openvdb::io::bloscToStream(os, v.data(), sizeof(char), v.size());
    else
        openvdb::io::zipToStream(os, v.data(), v.size());
    os.write("END!", 4);
    return os.str();
}

/// A stored chunk: a count of -n, then n bytes
std::string stored(const std::vector<char> &v, int64_t count) {
    std::string s(reinterpret_cast<const char *>(&count), 8);
    s.append(v.data(), v.size());
    return s + "END!";
}

struct Result {
    std::vector<char> data;
    std::streamoff at = -1;
    std::string error;
};

Result run(Reader f, const std::string &bytes, size_t numBytes, bool skip) {
    Result r;
    r.data.assign(numBytes, char(0x5a));
    std::istringstream is(bytes, std::ios_base::binary);
    try {
        f(is, skip ? nullptr : r.data.data(), numBytes);
        r.at = is.tellg();
    } catch (const std::exception &e) {
        r.error = e.what();
    }
    return r;
}

} // namespace

TEST_CASE("vdb_chunks: this process's calls reach the checked readers") {
    CHECK(nanovdb_loader::vdb_reader::chunk_readers_replaced());
}

TEST_CASE("vdb_chunks: well-formed chunks read as OpenVDB reads them") {
    const Reader blosc_up = upstream(reinterpret_cast<void *>(ours_blosc())),
                 zip_up = upstream(reinterpret_cast<void *>(ours_zip()));
    int cases = 0;
    for (size_t n : { size_t(0), size_t(1), size_t(17), size_t(512), size_t(4096),
                      size_t(6196), size_t(65536 + 3) }) {
        for (int kind = 0; kind < 3; ++kind) {
            std::vector<char> v = values(n, kind, uint32_t(n * 3 + kind));
            for (bool blosc : { true, false }) {
                const std::string s = chunk(v, blosc);
                for (bool skip : { false, true }) {
                    Result a = run(blosc ? ours_blosc() : ours_zip(), s, n, skip),
                           b = run(blosc ? blosc_up : zip_up, s, n, skip);
                    CAPTURE(n);
                    CAPTURE(kind);
                    CAPTURE(blosc);
                    CAPTURE(skip);
                    CHECK(a.error == b.error);
                    CHECK(a.error.empty());
                    CHECK(a.at == b.at);
                    CHECK(a.at == std::streamoff(s.size() - 4));
                    CHECK(a.data == b.data);
                    if (!skip)
                        CHECK(a.data == v);
                    ++cases;
                }
            }
            // A stored chunk (what OpenVDB writes when compression does not pay)
            const std::string s = stored(v, -int64_t(n));
            for (Reader f : { ours_blosc(), ours_zip() }) {
                Result a = run(f, s, n, false);
                CHECK(a.error.empty());
                CHECK(a.data == v);
                CHECK(a.at == std::streamoff(s.size() - 4));
            }
        }
    }
    CHECK(cases == 7 * 3 * 2 * 2);
}

TEST_CASE("vdb_chunks: damaged chunks are errors, not writes past the buffer") {
    const size_t n = 512;
    std::vector<char> v = values(n, 0, 7);
    auto error_of = [&](Reader f, const std::string &s, size_t numBytes = 512) {
        Result r = run(f, s, numBytes, false);
        CHECK(r.data.size() == numBytes); // (nothing past it was touched: ASan builds)
        return r.error;
    };
    SUBCASE("a stored chunk larger than the node") {
        std::string s = stored(values(4096, 1, 1), -4096);
        for (Reader f : { ours_blosc(), ours_zip() })
            CHECK(error_of(f, s).find("an uncompressed") != std::string::npos);
        CHECK(error_of(ours_blosc(), s).find("declares 4096 bytes where the node holds 512 bytes") !=
              std::string::npos);
    }
    SUBCASE("a stored chunk of -2^63 bytes") {
        CHECK(error_of(ours_blosc(), stored({}, INT64_MIN)).find("-2^63") != std::string::npos);
    }
    SUBCASE("a compressed count beyond what blosc or zlib can make of the node") {
        std::string s = chunk(v, true);
        int64_t huge = int64_t(1) << 40;
        std::memcpy(s.data(), &huge, 8);
        CHECK(error_of(ours_blosc(), s).find("at most 528 bytes can be valid") != std::string::npos);
        std::string z = chunk(v, false);
        std::memcpy(z.data(), &huge, 8);
        CHECK(error_of(ours_zip(), z).find("can be valid") != std::string::npos);
    }
    SUBCASE("a chunk cut short by the end of the file") {
        std::string s = chunk(values(4096, 1, 3), true);
        s.resize(s.size() / 2);
        CHECK(error_of(ours_blosc(), s, 4096).find("is cut short") != std::string::npos);
        CHECK(error_of(ours_blosc(), s.substr(0, 5), 4096).find("ends inside") != std::string::npos);
    }
    SUBCASE("a blosc header that claims more bytes than the chunk has") {
        std::string s = chunk(values(4096, 1, 4), true);
        // blosc's header: version, versionlz, flags, typesize, then nbytes,
        // blocksize, cbytes (little-endian uint32 each) after the count
        uint32_t cbytes = 0;
        std::memcpy(&cbytes, s.data() + 8 + 12, 4);
        cbytes += 1000;
        std::memcpy(s.data() + 8 + 12, &cbytes, 4);
        CHECK(error_of(ours_blosc(), s, 4096).find("corrupt header") != std::string::npos);
    }
    SUBCASE("a blosc chunk of another size than the node") {
        std::string s = chunk(values(256, 0, 5), true);
        CHECK(error_of(ours_blosc(), s, 512).find("decompresses to 256 bytes") != std::string::npos);
    }
    SUBCASE("corrupt zlib data") {
        std::string z = chunk(values(4096, 0, 6), false);
        for (size_t i = 10; i < z.size() - 4; i += 3)
            z[i] = char(z[i] ^ 0x55);
        CHECK(error_of(ours_zip(), z, 4096).find("does not decompress") != std::string::npos);
    }
}
