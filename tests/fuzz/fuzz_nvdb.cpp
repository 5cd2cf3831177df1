// libFuzzer harness over the .nvdb loader (src/loader/: container, validation,
// value policy, reader policy) and a batch of scalar lookups with the Dr.Jit
// translation of PNanoVDB through the plugin's readers (include/nanovdb_drjit/).
//
// One input = the bytes of a file. It is written to a memfd and read through
// its /proc/self/fd path, exactly as the plugin reads a file, and decoded by
// the plugin's own decode path (nanovdb_loader::decode_grid):
//   list_grids -> select_grid("") -> read_grid -> validate_grid
//   -> value policy "error" (and, on a copy, "clamp": sanitize_values)
//   -> plan_readers -> lookups through nanovdb_drjit::Reader with that plan
//      and with PNanoVDB's own algorithm: root_get_value and
//      root_get_stencil_addresses at coordinates derived from the input
//      (bbox corners, node boundaries, raw int32s).
// Every value type the loader accepts (float, Half, Fp4/8/16, FpN, Vec3f) is
// looked up with its own readers and compared with PNanoVDB's per-type ones.
// Oracles, besides ASan/UBSan:
//  * the decoded grid sits in a GuardedBuffer (tests/guarded_buffer.h): any
//    read past it faults, however far;
//  * every value address is checked to lie inside the buffer;
//  * every lookup is compared with PNanoVDB itself (C, 64-bit addresses):
//    same value address and level; each stencil corner equals a traversal;
//  * nanovdb_loader::Error is the only exception allowed.
//
// Build: cmake -DNVDB_BUILD_FUZZ=ON with clang (tests/fuzz/CMakeLists.txt).
// Run:   fuzz_nvdb CORPUS_DIR [SEED_DIRS...] -max_total_time=30

#define PNANOVDB_C
#define PNANOVDB_ADDRESS_64
#include <nanovdb/PNanoVDB.h>

#include <nanovdb_drjit/fast_readers.h>
#include <nanovdb_drjit/pnanovdb.h>
#include <nanovdb_drjit/stencil.h>
#include <nanovdb_loader/load.h>
#include "../../src/loader/value_codec.h"

#include "../guarded_buffer.h"

#include <sys/mman.h>
#include <unistd.h>

#include <array>
#include <cmath>
#include <optional>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

namespace nio = nanovdb_loader;
namespace ndr = nanovdb_drjit;
namespace dr = drjit;

namespace {

[[noreturn]] void die(const char *what, uint64_t a = 0, uint64_t b = 0) {
    std::fprintf(stderr, "fuzz_nvdb: %s (%llu, %llu)\n", what, (unsigned long long) a,
                 (unsigned long long) b);
    std::abort();
}

/// The input as a file: a memfd, named by its /proc/self/fd path.
struct MemFile {
    int fd = -1;
    std::string path;
    MemFile(const uint8_t *data, size_t size) {
        fd = memfd_create("nvdb_fuzz", 0);
        if (fd < 0) die("memfd_create failed");
        size_t done = 0;
        while (done < size) {
            const ssize_t n = write(fd, data + done, size - done);
            if (n <= 0) die("write to memfd failed");
            done += size_t(n);
        }
        path = "/proc/self/fd/" + std::to_string(fd);
    }
    ~MemFile() { close(fd); }
};

struct Reader { // bytes of the input, consumed from the end, for coordinates
    const uint8_t *p;
    size_t n;
    uint32_t u32() {
        uint32_t v = 0;
        for (int i = 0; i < 4 && n > 0; ++i) v = (v << 8) | p[--n];
        return v;
    }
};

/// PNanoVDB's value (its per-type reader) at an address and level, as the
/// bits of up to 3 floats (the translation's value: root_read_float /
/// root_read_vec3f)
template <uint32_t T>
std::array<uint32_t, 3> pnanovdb_value(pnanovdb_buf_t pbuf, pnanovdb_address_t a,
                                       pnanovdb_coord_t *ijk, uint32_t level) {
    float v[3] = { 0.f, 0.f, 0.f };
    switch (T) {
        case PNANOVDB_GRID_TYPE_FP4: v[0] = pnanovdb_root_fp4_read_float(pbuf, a, ijk, level); break;
        case PNANOVDB_GRID_TYPE_FP8: v[0] = pnanovdb_root_fp8_read_float(pbuf, a, ijk, level); break;
        case PNANOVDB_GRID_TYPE_FP16: v[0] = pnanovdb_root_fp16_read_float(pbuf, a, ijk, level); break;
        case PNANOVDB_GRID_TYPE_FPN: v[0] = pnanovdb_root_fpn_read_float(pbuf, a, ijk, level); break;
        case PNANOVDB_GRID_TYPE_HALF: // F16C-exact (tests/test_value_types.cpp)
            v[0] = nio::detail::half_to_float(uint16_t(pnanovdb_read_half(pbuf, a))); break;
        case PNANOVDB_GRID_TYPE_VEC3F:
            for (uint32_t k = 0; k < 3; ++k)
                v[k] = pnanovdb_read_float(pbuf, pnanovdb_address_offset(a, 4 * k));
            break;
        default: v[0] = pnanovdb_read_float(pbuf, a);
    }
    std::array<uint32_t, 3> bits;
    std::memcpy(bits.data(), v, 12);
    return bits;
}

/// The translation's value at an address and level, as pnanovdb_value()
template <uint32_t T, typename Buffer>
std::array<uint32_t, 3> translation_value(const Buffer &buf, uint32_t address, uint32_t level,
                                          const ndr::Coord<uint32_t> &ijk) {
    float v[3] = { 0.f, 0.f, 0.f };
    if constexpr (T == ndr::layout::GRID_TYPE_VEC3F) {
        auto x = ndr::root_read_vec3f<T>(buf, address, true);
        for (int k = 0; k < 3; ++k) v[k] = x[k];
    } else {
        v[0] = ndr::root_read_float<T>(buf, address, level, ijk, true);
    }
    std::array<uint32_t, 3> bits;
    std::memcpy(bits.data(), v, 12);
    return bits;
}

/// Calls fn(std::integral_constant<uint32_t, T>) for the grid's value type
template <typename Fn> void with_type(uint32_t grid_type, Fn &&fn) {
    ndr::layout::visit_value_type(grid_type, std::forward<Fn>(fn));
}

/// Lookups through one reader (the plan's or the faithful one) against PNanoVDB
template <uint32_t T, typename Root, typename Buffer>
void lookups(const Buffer &buf, const Root &root, const nio::ValidatedGrid &grid,
             const uint8_t *input, size_t input_size) {
    const uint32_t *words = grid.words();
    const uint64_t word_count = (grid.bytes() + 3) / 4;
    pnanovdb_buf_t pbuf;
    pbuf.data = const_cast<uint32_t *>(words);
    pnanovdb_root_handle_t proot = { uint64_t(grid.summary().root_word) * 4 };
    const nio::GridSummary &info = grid.summary();

    std::vector<std::array<int32_t, 3>> coords;
    const int32_t *lo = info.bbox_min, *hi = info.bbox_max;
    for (int c = 0; c < 8; ++c)
        coords.push_back({ (c & 1) ? hi[0] : lo[0], (c & 2) ? hi[1] : lo[1],
                           (c & 4) ? hi[2] : lo[2] });
    Reader rd{ input, input_size };
    const int32_t deltas[] = { 0, -1, 1, 7, 8, 127, 128, 4095, 4096 };
    for (int i = 0; i < 40; ++i) {
        const uint32_t r = rd.u32();
        std::array<int32_t, 3> c;
        for (int k = 0; k < 3; ++k) {
            const uint32_t s = rd.u32();
            switch (r >> (8 * k) & 3) {
                case 0: c[k] = int32_t(s); break;                           // anywhere
                case 1: c[k] = int32_t(uint32_t(lo[k]) + (s & 255u)); break;  // near bbox min
                case 2: c[k] = int32_t(uint32_t(hi[k]) - (s & 255u)); break;  // near bbox max
                default: c[k] = int32_t(uint32_t(s & ~4095u) + uint32_t(deltas[s % 9])); // node edges
            }
        }
        coords.push_back(c);
    }

    for (const auto &c : coords) {
        // One traversal: translation vs PNanoVDB
        ndr::Coord<uint32_t> ijk(c[0], c[1], c[2]);
        ndr::AddressAndLevel<uint32_t> al = ndr::root_get_value_address_and_level<T>(
            buf, root, ijk, true);
        pnanovdb_coord_t pijk = { c[0], c[1], c[2] };
        pnanovdb_uint32_t plevel = 0;
        pnanovdb_address_t paddr = pnanovdb_root_get_value_address_and_level(
            T, pbuf, proot, &pijk, &plevel);
        if (al.address >= word_count) die("value address outside the buffer", al.address, word_count);
        // Half leaf values are 2-byte aligned: the translation addresses their word
        if (uint64_t(al.address) * 4 != (paddr.byte_offset & ~uint64_t(3)) || al.level != plevel)
            die("translation and PNanoVDB disagree", uint64_t(al.address) * 4, paddr.byte_offset);
        if (translation_value<T>(buf, al.address, al.level, ijk) !=
            pnanovdb_value<T>(pbuf, paddr, &pijk, plevel))
            die("values differ");

        // A trilinear stencil with c as its first corner (+1 wraps at
        // INT32_MAX in both readers: int32 wrap-around, done in uint32 here)
        std::array<int32_t, 3> c0 = c;
        ndr::Coord<uint32_t> ijk0(c0[0], c0[1], c0[2]);
        dr::Array<uint32_t, 8> st = ndr::root_get_stencil_addresses<T>(buf, root, ijk0, true);
        for (uint32_t corner = 0; corner < 8; ++corner) {
            auto plus = [](int32_t v, uint32_t b) { return int32_t(uint32_t(v) + b); };
            pnanovdb_coord_t q = { plus(c0[0], corner & 1), plus(c0[1], (corner >> 1) & 1),
                                   plus(c0[2], (corner >> 2) & 1) };
            pnanovdb_address_t a = pnanovdb_root_get_value_address(T, pbuf, proot, &q);
            if (st[corner] >= word_count) die("stencil address outside the buffer", st[corner]);
            if (uint64_t(st[corner]) * 4 != (a.byte_offset & ~uint64_t(3)))
                die("stencil corner differs from PNanoVDB", corner, a.byte_offset);
        }
    }
}

} // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    MemFile file(data, size);
    try {
        const std::vector<nio::GridEntry> grids = nio::list_grids(file.path);
        const nio::GridEntry &entry = nio::select_grid(file.path, grids, "");
        // 1100:1 compression can ask for much; keep within libFuzzer's RSS limit
        if (entry.grid_size > (uint64_t(256) << 20))
            return 0;
        nvdb_test::GuardedBuffer buf(entry.grid_size);

        // The plugin's decode path with invalid_values="clamp" on a copy first
        // (the "error" policy may refuse the grid): sanitizing leaves no NaN,
        // Inf or negative value, and a finite max() >= 0
        {
            nvdb_test::GuardedBuffer copy(entry.grid_size);
            nio::DecodedGrid clamped = nio::decode_grid(file.path, entry, copy.data(), copy.size(),
                                                        nio::InvalidValues::Clamp);
            const nio::ValueStats &v = clamped.grid.values();
            if (v.nan_count || v.posinf_count || v.neginf_count || v.negative_count)
                die("clamp left invalid values", v.nan_count, v.negative_count);
            if (!(v.max >= 0.f) || std::isinf(v.max))
                die("clamped max is not finite and >= 0");
            // ... and a second validation of the sanitized bytes agrees
            const nio::ValidatedGrid again =
                nio::validate_grid(file.path, copy.data(), entry.grid_size);
            if (std::memcmp(&again.values().max, &v.max, 4) != 0 ||
                again.values().value_count != v.value_count)
                die("sanitized statistics differ from a fresh validation");
        }

        std::optional<nio::DecodedGrid> decoded;
        try {
            decoded.emplace(nio::decode_grid(file.path, entry, buf.data(), buf.size(),
                                             nio::InvalidValues::Error));
        } catch (const nio::Error &) {
            // refused (maybe for its values only): validate alone, look up anyway
            nio::ValidatedGrid grid = nio::validate_grid(file.path, buf.data(), entry.grid_size);
            nio::ReaderPlan plan = nio::plan_readers(grid);
            decoded.emplace(nio::DecodedGrid{ std::move(grid), std::move(plan), {} });
        }
        const nio::ValueScan scan = nio::scan_values(decoded->grid);
        (void) nio::describe_invalid_values(scan);

        const uint32_t *words = decoded->grid.words();
        for (const nio::ReaderPlan &plan : { decoded->plan, decoded->plan.faithful() }) {
            with_type(decoded->grid.summary().grid_type, [&](auto type) {
                ndr::Reader<uint32_t>::from_plan(plan).apply(words, [&](const auto &b, const auto &root) {
                    lookups<decltype(type)::value>(b, root, decoded->grid, data, size);
                });
            });
        }
    } catch (const nio::Error &) {
        // the only failure allowed: a clear error
    }
    return 0;
}
