// src/loader/detail.h -- small helpers shared by the loader's modules
// (container.cpp, validation.cpp, values.cpp, reader_policy.cpp, the
// majorants). Internal:
// not installed, not included by the plugin.
#pragma once

#include <nanovdb_loader/container.h>
#include <nanovdb_drjit/layout.h>

#include <cstdint>
#include <cstring>
#include <string>

namespace nanovdb_loader {

namespace layout = nanovdb_drjit::layout;

namespace detail {

/// Largest decoded grid we accept: the reader addresses 32-bit words (16 GiB).
constexpr uint64_t kMaxGridBytes = uint64_t(1) << 34;

// ---- Small helpers ------------------------------------------------------------

/// Unaligned little-endian load (the host is assumed little-endian, as every
/// platform Mitsuba supports is).
template <typename T> inline T load(const uint8_t *p) {
    T v;
    std::memcpy(&v, p, sizeof(T));
    return v;
}

/// Unaligned little-endian store, load()'s pair
template <typename T> inline void store(uint8_t *p, T v) { std::memcpy(p, &v, sizeof(T)); }

using layout::version_major;

/// a + b on int32 coordinates with wrap-around, as the lookups' coordinates
/// wrap (plain int32 overflow would be undefined)
inline int32_t wrap_add(int32_t a, int64_t b) { return int32_t(uint32_t(a) + uint32_t(b)); }

inline std::string version_string(uint32_t v) {
    return std::to_string(v >> 21) + "." + std::to_string((v >> 10) & 0x7ffu) +
           "." + std::to_string(v & 0x3ffu);
}

/// "0x0000040000100000"
inline std::string hex64(uint64_t v) {
    static const char *digits = "0123456789abcdef";
    std::string s = "0x";
    for (int i = 15; i >= 0; --i)
        s += digits[(v >> (4 * i)) & 15u];
    return s;
}

inline uint64_t byte_swap64(uint64_t v) {
    uint64_t r = 0;
    for (int i = 0; i < 8; ++i)
        r = (r << 8) | ((v >> (8 * i)) & 0xffu);
    return r;
}

inline bool is_byte_swapped_magic(uint64_t m) {
    return m == byte_swap64(layout::MAGIC_NUMBER) || m == byte_swap64(layout::MAGIC_GRID) ||
           m == byte_swap64(layout::MAGIC_FILE);
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

/// Name stored in a fixed-size, possibly unterminated, character field
/// (printable_text: a damaged name's stray bytes become \xNN)
inline std::string fixed_string(const uint8_t *p, size_t n) {
    size_t len = 0;
    while (len < n && p[len] != 0) ++len;
    return printable_text(std::string(reinterpret_cast<const char *>(p), len));
}

[[noreturn]] inline void fail(const std::string &path, const std::string &msg) {
    throw Error("\"" + path + "\": " + msg);
}


} // namespace detail
} // namespace nanovdb_loader
