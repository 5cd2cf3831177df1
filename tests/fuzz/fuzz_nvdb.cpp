// libFuzzer harness over the .nvdb loader (include/nanovdb_drjit/io.h), the
// validator, the value scan/sanitizer and a batch of scalar lookups with the
// Dr.Jit translation of PNanoVDB (include/nanovdb_drjit/pnanovdb.h, read only).
//
// One input = the bytes of a file. It is written to a memfd and read through
// its /proc/self/fd path, exactly as the plugin reads a file:
//   list_grids -> select_grid("") -> read_grid -> validate_float_grid
//   -> scan_values -> (on a copy) sanitize_values + validate again
//   -> lookups: root_get_value and root_get_stencil_addresses at coordinates
//      derived from the input (bbox corners, node boundaries, raw int32s).
// Oracles, besides ASan/UBSan:
//  * the decoded grid sits at the end of a mapping followed by 16 GiB of
//    PROT_NONE address space (all that a 32-bit word address can reach), so
//    any read past the buffer faults, however far;
//  * every value address is checked to lie inside the buffer;
//  * every lookup is compared with PNanoVDB itself (C, 64-bit addresses):
//    same value address and level; each stencil corner equals a traversal;
//  * io::Error is the only exception allowed.
//
// Build: cmake -DNVDB_BUILD_FUZZ=ON with clang (tests/fuzz/CMakeLists.txt).
// Run:   fuzz_nvdb CORPUS_DIR [SEED_DIRS...] -max_total_time=30

#define PNANOVDB_C
#define PNANOVDB_ADDRESS_64
#include <nanovdb/PNanoVDB.h>

#include <nanovdb_drjit/io.h>
#include <nanovdb_drjit/pnanovdb.h>

#include <sys/mman.h>
#include <unistd.h>

#include <array>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

namespace nio = nanovdb_drjit::io;
namespace ndr = nanovdb_drjit;
namespace dr = drjit;

namespace {

[[noreturn]] void die(const char *what, uint64_t a = 0, uint64_t b = 0) {
    std::fprintf(stderr, "fuzz_nvdb: %s (%llu, %llu)\n", what, (unsigned long long) a,
                 (unsigned long long) b);
    std::abort();
}

/// A region of `bytes` (rounded up to 32) that ends exactly where 16 GiB + a
/// page of PROT_NONE address space begins.
struct GuardedBuffer {
    uint8_t *base = nullptr, *data = nullptr;
    size_t total = 0;
    explicit GuardedBuffer(uint64_t bytes) {
        const size_t page = size_t(sysconf(_SC_PAGESIZE));
        const size_t rounded = size_t((bytes + 31) / 32 * 32);
        const size_t head = (rounded + page - 1) / page * page;
        const size_t guard = (size_t(1) << 34) + page;
        total = head + guard;
        void *p = mmap(nullptr, total, PROT_NONE, MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE,
                       -1, 0);
        if (p == MAP_FAILED) die("mmap of the guard region failed", total);
        base = static_cast<uint8_t *>(p);
        if (head && mprotect(base, head, PROT_READ | PROT_WRITE) != 0)
            die("mprotect failed", head);
        data = base + head - rounded; // 32-byte aligned (page - multiple of 32)
        std::memset(data, 0, rounded);
    }
    ~GuardedBuffer() { munmap(base, total); }
    GuardedBuffer(const GuardedBuffer &) = delete;
    GuardedBuffer &operator=(const GuardedBuffer &) = delete;
};

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

void lookups(const uint8_t *buf, uint64_t bytes, const nio::FloatGridInfo &info,
             const uint8_t *input, size_t input_size) {
    const uint32_t *words = reinterpret_cast<const uint32_t *>(buf);
    const uint64_t word_count = (bytes + 3) / 4;
    pnanovdb_buf_t pbuf;
    pbuf.data = const_cast<uint32_t *>(words);
    pnanovdb_root_handle_t proot = { uint64_t(info.root_word) * 4 };
    ndr::RootHandle<uint32_t> root{ info.root_word };

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
        ndr::AddressAndLevel<uint32_t> al = ndr::root_get_value_address_and_level(
            words, root, ijk, true);
        pnanovdb_coord_t pijk = { c[0], c[1], c[2] };
        pnanovdb_uint32_t plevel = 0;
        pnanovdb_address_t paddr = pnanovdb_root_get_value_address_and_level(
            PNANOVDB_GRID_TYPE_FLOAT, pbuf, proot, &pijk, &plevel);
        if (al.address >= word_count) die("value address outside the buffer", al.address, word_count);
        if (uint64_t(al.address) * 4 != paddr.byte_offset || al.level != plevel)
            die("translation and PNanoVDB disagree", uint64_t(al.address) * 4, paddr.byte_offset);
        const float v = ndr::root_get_value(words, root, ijk, true);
        float pv = pnanovdb_read_float(pbuf, paddr);
        if (std::memcmp(&v, &pv, 4) != 0) die("values differ");

        // A trilinear stencil with c as its first corner (+1 wraps at
        // INT32_MAX in both readers: int32 wrap-around, done in uint32 here)
        std::array<int32_t, 3> c0 = c;
        ndr::Coord<uint32_t> ijk0(c0[0], c0[1], c0[2]);
        dr::Array<uint32_t, 8> st = ndr::root_get_stencil_addresses(words, root, ijk0, true);
        for (uint32_t corner = 0; corner < 8; ++corner) {
            auto plus = [](int32_t v, uint32_t b) { return int32_t(uint32_t(v) + b); };
            pnanovdb_coord_t q = { plus(c0[0], corner & 1), plus(c0[1], (corner >> 1) & 1),
                                   plus(c0[2], (corner >> 2) & 1) };
            pnanovdb_address_t a = pnanovdb_root_get_value_address(PNANOVDB_GRID_TYPE_FLOAT, pbuf,
                                                                   proot, &q);
            if (st[corner] >= word_count) die("stencil address outside the buffer", st[corner]);
            if (uint64_t(st[corner]) * 4 != a.byte_offset)
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
        GuardedBuffer buf(entry.grid_size);
        nio::read_grid(file.path, entry, buf.data);
        const nio::FloatGridInfo info = nio::validate_float_grid(file.path, buf.data, entry.grid_size);
        const nio::ValueScan scan = nio::scan_values(file.path, buf.data, entry.grid_size);
        if (scan.nan_count != info.nan_count ||
            scan.posinf_count + scan.neginf_count != info.inf_count)
            die("scan_values and validate_float_grid count differently", scan.nan_count,
                info.nan_count);
        (void) nio::describe_invalid_values(scan);
        lookups(buf.data, entry.grid_size, info, data, size);

        // Sanitize a copy; the result validates and holds no NaN/Inf/negative
        GuardedBuffer copy(entry.grid_size);
        std::memcpy(copy.data, buf.data, size_t(entry.grid_size));
        nio::sanitize_values(file.path, copy.data, entry.grid_size);
        const nio::ValueScan after = nio::scan_values(file.path, copy.data, entry.grid_size);
        if (after.nan_count || after.posinf_count || after.neginf_count || after.negative_count)
            die("sanitize_values left invalid values", after.nan_count, after.negative_count);
        const nio::FloatGridInfo info2 = nio::validate_float_grid(file.path, copy.data, entry.grid_size);
        if (!(info2.value_max >= 0.f) || std::isinf(info2.value_max))
            die("sanitized value_max is not finite and >= 0");
    } catch (const nio::Error &) {
        // the only failure allowed: a clear error
    }
    return 0;
}
