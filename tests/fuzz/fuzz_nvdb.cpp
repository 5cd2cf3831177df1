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
//      (bbox corners, node boundaries, raw int32s);
//   -> the fast reader against the faithful one at the coordinates that the
//      grid's tree touches (its tiles, nodes and voxels, and their borders).
// Every value type the loader accepts (float, Half, Fp4/8/16, FpN, Vec3f) is
// looked up with its own readers and compared with PNanoVDB's per-type ones.
// Oracles, besides ASan/UBSan:
//  * the decoded grid sits in a GuardedBuffer (tests/guarded_buffer.h): any
//    read past it faults, however far;
//  * every value address is checked to lie inside the buffer;
//  * every lookup is compared with PNanoVDB itself (C, 64-bit addresses):
//    same value address and level; each stencil corner equals a traversal;
//  * the differential oracle: the tree is walked with PNanoVDB's C API (root
//    tiles by key, upper/lower children and active tiles, leaves and a few
//    of their active voxels) and at each block's first and last voxel and
//    the voxels just outside it (origin - 1, origin + extent), at most ~2000
//    coordinates a grid, the fast reader (the plan's) and the faithful
//    translation (plan.faithful()) must find the same level, value address
//    and value bits, and both what PNanoVDB finds;
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
#include "mem_file.h"

#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
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

using nvdb_fuzz::MemFile; // (mem_file.h)

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

// ---------------------------------------------------------------------------
//  The differential oracle: fast reader vs faithful translation, at the
//  coordinates the input's tree touches
// ---------------------------------------------------------------------------

using Coord3 = std::array<int32_t, 3>;

/// c + d on every axis, with int32 wrap-around (done in uint32: no UB)
Coord3 offset(const Coord3 &c, int32_t d) {
    return { int32_t(uint32_t(c[0]) + uint32_t(d)), int32_t(uint32_t(c[1]) + uint32_t(d)),
             int32_t(uint32_t(c[2]) + uint32_t(d)) };
}
/// o + (x, y, z) * scale, as offset()
Coord3 offset(const Coord3 &o, uint32_t x, uint32_t y, uint32_t z, uint32_t scale) {
    return { int32_t(uint32_t(o[0]) + x * scale), int32_t(uint32_t(o[1]) + y * scale),
             int32_t(uint32_t(o[2]) + z * scale) };
}

/// Coordinates in groups, one per tile, node or leaf, so that sampling keeps
/// a group whole (both sides of a boundary)
struct Groups {
    std::vector<Coord3> coords;
    std::vector<uint32_t> begin; ///< first coordinate of each group
    size_t size() const { return begin.size(); }
    void open() { begin.push_back(uint32_t(coords.size())); }
    /// A block of `extent`^3 voxels at `o` (a tile or a node): its first and
    /// last voxel, and the voxels just outside it on either side, where holes
    /// hide (o - 1 and o + extent, on every axis)
    void block(const Coord3 &o, uint32_t extent) {
        open();
        coords.push_back(o);
        coords.push_back(offset(o, int32_t(extent - 1)));
        coords.push_back(offset(o, -1));
        coords.push_back(offset(o, int32_t(extent)));
    }
};

/// The walk's bounds (tree order; a grid past them is walked in part):
/// groups per level, nodes visited per level
constexpr size_t MAX_GROUPS = size_t(1) << 14;
constexpr size_t MAX_UPPERS = 256, MAX_LOWERS = 4096, MAX_LEAVES = size_t(1) << 14;

/**
 * The tiles, nodes and voxels of a validated tree, walked with PNanoVDB's C
 * API from the root, one group of coordinates each (Groups::block), by level:
 *  [0] every root tile, at the block of its key (child or not);
 *  [1] per upper node: each child and active tile (128^3), and its first and
 *      last entry;
 *  [2] per lower node: the same (8^3);
 *  [3] per leaf: its block, up to 4 active voxels (first, last, two between)
 *      and its stored bbox_min (NanoVDB's is the first active voxel's
 *      corner: the origin is bbox_min & ~7) where that is not its origin.
 * Origins come from the path (key, then table index), as a lookup finds
 * them, not from the nodes' bboxes. A child reached twice is walked twice.
 */
template <uint32_t T>
std::array<Groups, 4> walk_tree(const nio::ValidatedGrid &grid) {
    pnanovdb_buf_t pbuf;
    pbuf.data = const_cast<uint32_t *>(grid.words());
    const pnanovdb_root_handle_t proot = { uint64_t(grid.summary().root_word) * 4 };
    std::array<Groups, 4> g;
    std::vector<std::pair<pnanovdb_upper_handle_t, Coord3>> uppers;
    std::vector<std::pair<pnanovdb_lower_handle_t, Coord3>> lowers;
    std::vector<std::pair<pnanovdb_leaf_handle_t, Coord3>> leaves;

    const uint32_t tiles = pnanovdb_root_get_tile_count(pbuf, proot);
    for (uint32_t t = 0; t < tiles && g[0].size() < MAX_GROUPS; ++t) {
        const pnanovdb_root_tile_handle_t tile = pnanovdb_root_get_tile(T, proot, t);
        // coord_to_key: 20 bits of ijk >> 12 per 21-bit field (validated)
        const uint64_t key = pnanovdb_root_tile_get_key(pbuf, tile);
        const Coord3 o = offset({ 0, 0, 0 }, uint32_t(key >> 42) & 0x1FFFFFu,
                                uint32_t(key >> 21) & 0x1FFFFFu, uint32_t(key) & 0x1FFFFFu, 4096u);
        g[0].block(o, 4096);
        if (pnanovdb_root_tile_get_child(pbuf, tile) != 0 && uppers.size() < MAX_UPPERS)
            uppers.push_back({ pnanovdb_root_get_child(T, pbuf, proot, tile), o });
    }
    // An internal node's entries: children and active tiles, and its corners
    auto entries = [&](pnanovdb_address_t node, uint32_t value_mask_off, uint32_t child_mask_off,
                       uint32_t log2_dim, uint32_t child_extent, const Coord3 &o, Groups &out,
                       auto &&child) {
        const uint32_t count = 1u << (3 * log2_dim), dim_mask = (1u << log2_dim) - 1u;
        auto at = [&](uint32_t n) {
            return offset(o, n >> (2 * log2_dim), (n >> log2_dim) & dim_mask, n & dim_mask,
                          child_extent);
        };
        for (uint32_t w = 0; w < count / 32; ++w) {
            const uint32_t value = pnanovdb_read_uint32(
                pbuf, pnanovdb_address_offset(node, value_mask_off + 4 * w));
            const uint32_t kids = pnanovdb_read_uint32(
                pbuf, pnanovdb_address_offset(node, child_mask_off + 4 * w));
            uint32_t bits = value | kids;
            if (w == 0) bits |= 1u;                   // first entry
            if (w == count / 32 - 1) bits |= 1u << 31; // last entry
            for (; bits && out.size() < MAX_GROUPS; bits &= bits - 1) {
                const uint32_t n = 32 * w + uint32_t(__builtin_ctz(bits));
                out.block(at(n), child_extent);
                if (kids >> (n & 31) & 1u) child(n, at(n));
            }
        }
    };
    for (const auto &u : uppers)
        entries(u.first.address, PNANOVDB_UPPER_OFF_VALUE_MASK, PNANOVDB_UPPER_OFF_CHILD_MASK, 5,
                128, u.second, g[1], [&](uint32_t n, const Coord3 &c) {
                    if (lowers.size() < MAX_LOWERS)
                        lowers.push_back({ pnanovdb_upper_get_child(T, pbuf, u.first, n), c });
                });
    for (const auto &l : lowers)
        entries(l.first.address, PNANOVDB_LOWER_OFF_VALUE_MASK, PNANOVDB_LOWER_OFF_CHILD_MASK, 4,
                8, l.second, g[2], [&](uint32_t n, const Coord3 &c) {
                    if (leaves.size() < MAX_LEAVES)
                        leaves.push_back({ pnanovdb_lower_get_child(T, pbuf, l.first, n), c });
                });
    for (const auto &lf : leaves) {
        if (g[3].size() >= MAX_GROUPS) break;
        const pnanovdb_leaf_handle_t leaf = lf.first;
        const Coord3 &o = lf.second;
        g[3].block(o, 8);
        // Active voxels: the first, the last and two between, by rank
        uint32_t mask[16], active = 0;
        for (uint32_t w = 0; w < 16; ++w) {
            mask[w] = pnanovdb_read_uint32(
                pbuf, pnanovdb_address_offset(leaf.address, PNANOVDB_LEAF_OFF_VALUE_MASK + 4 * w));
            active += uint32_t(__builtin_popcount(mask[w]));
        }
        for (uint32_t n = 0, rank = 0; n < 512 && rank < active; ++n) {
            if (!(mask[n >> 5] >> (n & 31) & 1u)) continue;
            if (rank == 0 || rank == active / 3 || rank == 2 * active / 3 || rank == active - 1)
                g[3].coords.push_back(offset(o, n >> 6, (n >> 3) & 7, n & 7, 1));
            ++rank;
        }
        const pnanovdb_coord_t b = pnanovdb_leaf_get_bbox_min(pbuf, leaf);
        if (b.x != o[0] || b.y != o[1] || b.z != o[2])
            g[3].coords.push_back({ b.x, b.y, b.z });
    }
    return g;
}

/**
 * At most `budget` coordinates of the walk, in whole groups: each level gets
 * an equal share of what the levels before it left; a level with more
 * groups than its share gets evenly spaced ones, from an input-dependent
 * start (`salt`), so that the fuzzer reaches every group of a large grid
 * across inputs.
 */
std::vector<Coord3> sample(const std::array<Groups, 4> &g, size_t budget, uint32_t salt) {
    std::vector<Coord3> out;
    for (size_t level = 0; level < 4; ++level) {
        const Groups &l = g[level];
        const size_t share = (budget - out.size()) / (4 - level), first = out.size();
        if (l.coords.size() <= share) {
            out.insert(out.end(), l.coords.begin(), l.coords.end());
            continue;
        }
        const size_t n = l.size(), per = (l.coords.size() + n - 1) / n; // coords per group, at most
        const size_t m = std::max<size_t>(1, share / per), step = std::max<size_t>(1, n / m);
        for (size_t i = salt % step; i < n; i += step) {
            const size_t b = l.begin[i], e = i + 1 < n ? l.begin[i + 1] : l.coords.size();
            if (out.size() - first + (e - b) > share) break;
            out.insert(out.end(), l.coords.begin() + b, l.coords.begin() + e);
        }
    }
    return out;
}

/// What one reader finds at a coordinate
struct Read {
    uint32_t address = 0, level = 0; ///< word address, PNanoVDB's level (0 leaf .. 4 background)
    std::array<uint32_t, 3> value{}; ///< as translation_value()
};

/// Every coordinate, through the reader a plan selects (its buffer and root handle)
template <uint32_t T>
std::vector<Read> read_all(const nio::ReaderPlan &plan, const uint32_t *words,
                           const std::vector<Coord3> &coords) {
    std::vector<Read> out(coords.size());
    ndr::Reader<uint32_t>::from_plan(plan).apply(words, [&](const auto &b, const auto &root) {
        for (size_t i = 0; i < coords.size(); ++i) {
            const Coord3 &c = coords[i];
            ndr::Coord<uint32_t> ijk(c[0], c[1], c[2]);
            ndr::AddressAndLevel<uint32_t> al =
                ndr::root_get_value_address_and_level<T>(b, root, ijk, true);
            out[i] = { al.address, al.level, translation_value<T>(b, al.address, al.level, ijk) };
        }
    });
    return out;
}

/// die() with the coordinate and what the two sides read there
[[noreturn]] void die_at(const char *what, const Coord3 &c, const char *a_name, const Read &a,
                         const char *b_name, const Read &b) {
    char msg[512];
    std::snprintf(msg, sizeof msg,
                  "%s at (%d, %d, %d): %s level %u, word %u, value bits %08x %08x %08x; "
                  "%s level %u, word %u, value bits %08x %08x %08x; levels",
                  what, c[0], c[1], c[2], a_name, a.level, a.address, a.value[0], a.value[1],
                  a.value[2], b_name, b.level, b.address, b.value[0], b.value[1], b.value[2]);
    die(msg, a.level, b.level);
}

/**
 * The differential oracle: at every coordinate the tree touches (walk_tree,
 * at most ~2000 a grid: fewer where many root tiles make each lookup slow),
 * the fast reader (the plan's: CompactOffsets, IndexedRootHandle) and the
 * faithful translation (plan.faithful()) find the same level, value address
 * and value bits, and so does PNanoVDB.
 */
template <uint32_t T>
void differential(const nio::DecodedGrid &decoded, const uint8_t *input, size_t input_size) {
    const nio::ValidatedGrid &grid = decoded.grid;
    // a lookup searches the root tiles linearly (faithful and PNanoVDB):
    // bound coordinates x tiles
    const size_t tiles = grid.summary().root_tile_count;
    const size_t budget = std::clamp<size_t>((size_t(1) << 22) / (tiles + 1), 256, 2000);
    uint32_t salt = 2166136261u ^ uint32_t(input_size); // FNV-1a of its first and last bytes
    for (size_t i = 0; i < input_size; i = (i == 63 && input_size > 128) ? input_size - 64 : i + 1)
        salt = (salt ^ input[i]) * 16777619u;
    const std::vector<Coord3> coords = sample(walk_tree<T>(grid), budget, salt);

    const uint32_t *words = grid.words();
    const uint64_t word_count = (grid.bytes() + 3) / 4;
    const std::vector<Read> fast = read_all<T>(decoded.plan, words, coords);
    const std::vector<Read> faithful = read_all<T>(decoded.plan.faithful(), words, coords);

    pnanovdb_buf_t pbuf;
    pbuf.data = const_cast<uint32_t *>(words);
    const pnanovdb_root_handle_t proot = { uint64_t(grid.summary().root_word) * 4 };
    for (size_t i = 0; i < coords.size(); ++i) {
        const Coord3 &c = coords[i];
        if (fast[i].address >= word_count || faithful[i].address >= word_count)
            die_at("differential: value address outside the buffer", c, "fast", fast[i],
                   "faithful", faithful[i]);
        if (fast[i].level != faithful[i].level || fast[i].address != faithful[i].address ||
            fast[i].value != faithful[i].value)
            die_at("differential: fast reader and faithful translation disagree", c, "fast",
                   fast[i], "faithful", faithful[i]);
        // ... and both read as PNanoVDB (the fast one through the faithful one)
        pnanovdb_coord_t pijk = { c[0], c[1], c[2] };
        pnanovdb_uint32_t plevel = 0;
        const pnanovdb_address_t paddr =
            pnanovdb_root_get_value_address_and_level(T, pbuf, proot, &pijk, &plevel);
        Read p;
        p.address = uint32_t(paddr.byte_offset >> 2); // Half: the word of a 2-byte value
        p.level = plevel;
        p.value = pnanovdb_value<T>(pbuf, paddr, &pijk, plevel);
        if (faithful[i].level != p.level || faithful[i].address != p.address ||
            faithful[i].value != p.value)
            die_at("differential: the translation and PNanoVDB disagree", c, "faithful",
                   faithful[i], "PNanoVDB", p);
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
        // The differential oracle, at the coordinates the tree touches
        with_type(decoded->grid.summary().grid_type, [&](auto type) {
            differential<decltype(type)::value>(*decoded, data, size);
        });
    } catch (const nio::Error &) {
        // the only failure allowed: a clear error
    }
    return 0;
}
