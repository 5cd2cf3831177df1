// nvdb_big_grid: a float grid of any size, streamed to disk without building
// it in memory, and PNanoVDB's reads of it.
//
//   nvdb_big_grid write OUT.nvdb LEAVES   raw grid buffer (the 32.6+ file form:
//                                         no segment header) with LEAVES full
//                                         leaves; prints its size and the
//                                         first coordinate whose value lies
//                                         past 4 GiB
//   nvdb_big_grid probe FILE i j k ...    PNanoVDB (C, 64-bit addresses) on
//                                         the mmapped file: one line per
//                                         coordinate "i j k level byte value"
//   nvdb_big_grid check FILE              NanoVDB 32.4's C++ API reads every
//                                         voxel of a (small) written file and
//                                         compares it with value_at()
//
// Layout (NanoVDB 32.x, float; offsets of PNanoVDB 32.4): GridData | TreeData |
// root (1 tile, key of the origin) | 1 upper node | L = ceil(LEAVES / 4096)
// lower nodes | LEAVES leaves. Lower node l is entry l of the upper node's
// table; its leaves fill its table in order; every voxel of every leaf is
// active, with value value_at(ijk) in [0.5, 1.5). Leaf n therefore lies at
// byte 272,000 + L * 33,856 + n * 2,144 or so: 2.3 M leaves reach 4.9 GB.
// The values do not depend on the layout, so any reader can check them.

#define PNANOVDB_C
#define PNANOVDB_ADDRESS_64
#include <nanovdb/PNanoVDB.h>

#include <iostream> // GridValidator.h uses std::cerr without including it

#include <nanovdb/NanoVDB.h>
#include <nanovdb/util/GridValidator.h>

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

namespace {

constexpr uint64_t kGrid = 672, kTree = 64, kRoot = 64, kTile = 32;
constexpr uint64_t kUpper = 270400, kLower = 33856, kLeaf = 2144;

float value_at(int32_t i, int32_t j, int32_t k) {
    uint32_t h = uint32_t(i) * 73856093u ^ uint32_t(j) * 19349663u ^ uint32_t(k) * 83492791u;
    h ^= h >> 13;
    h *= 0x5bd1e995u;
    h ^= h >> 15;
    return 0.5f + float(h & 0xffffu) / 65536.0f;
}

template <typename T> void put(std::vector<uint8_t> &b, uint64_t off, T v) {
    std::memcpy(b.data() + off, &v, sizeof(T));
}

struct Layout {
    uint64_t leaves, lowers, root, upper, lower0, leaf0, size;
    explicit Layout(uint64_t n) : leaves(n) {
        lowers = (n + 4095) / 4096;
        root = kGrid + kTree;
        upper = root + kRoot + kTile;   // 832: 32-byte aligned
        lower0 = upper + kUpper;
        leaf0 = lower0 + lowers * kLower;
        size = leaf0 + leaves * kLeaf;
    }
    // Origins: lower l at entry l of the upper table (32^3, x slowest);
    // leaf e of a lower at entry e of its table (16^3).
    static void lower_origin(uint64_t l, int32_t o[3]) {
        o[0] = int32_t((l >> 10) & 31) * 128; o[1] = int32_t((l >> 5) & 31) * 128;
        o[2] = int32_t(l & 31) * 128;
    }
    static void leaf_origin(uint64_t n, int32_t o[3]) {
        lower_origin(n / 4096, o);
        const uint64_t e = n % 4096;
        o[0] += int32_t((e >> 8) & 15) * 8; o[1] += int32_t((e >> 4) & 15) * 8;
        o[2] += int32_t(e & 15) * 8;
    }
};

int write_grid(const std::string &path, uint64_t n) {
    if (n == 0 || n > uint64_t(32768) * 4096) {
        std::fprintf(stderr, "nvdb_big_grid: LEAVES must be in [1, 2^27]\n");
        return 2;
    }
    const Layout L(n);
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    if (!out) { std::fprintf(stderr, "nvdb_big_grid: cannot write %s\n", path.c_str()); return 1; }

    // Bounding box of all leaves
    int32_t bmin[3] = { INT32_MAX, INT32_MAX, INT32_MAX }, bmax[3] = { INT32_MIN, INT32_MIN, INT32_MIN };
    // Exact bbox: scan every leaf origin (cheap: arithmetic only)
    for (uint64_t m = 0; m < n; ++m) {
        int32_t o[3];
        Layout::leaf_origin(m, o);
        for (int a = 0; a < 3; ++a) { bmin[a] = std::min(bmin[a], o[a]); bmax[a] = std::max(bmax[a], o[a] + 7); }
    }

    // Header: grid, tree, root, tile
    std::vector<uint8_t> h(L.upper, 0);
    std::memcpy(h.data(), "NanoVDB0", 8);
    put<uint64_t>(h, 8, ~uint64_t(0));                          // checksum: none
    put<uint32_t>(h, 16, (32u << 21) | (4u << 10) | 2u);        // 32.4.2
    put<uint32_t>(h, 20, 2u | 32u);                             // HasBBox | IsBreadthFirst
    put<uint32_t>(h, 28, 1u);                                   // grid count
    put<uint64_t>(h, 32, L.size);
    std::memcpy(h.data() + 40, "big", 3);
    const float id[9] = { 1, 0, 0, 0, 1, 0, 0, 0, 1 };
    const double idd[9] = { 1, 0, 0, 0, 1, 0, 0, 0, 1 };
    std::memcpy(h.data() + 296 + 0, id, 36);
    std::memcpy(h.data() + 296 + 36, id, 36);
    put<float>(h, 296 + 84, 1.f);
    std::memcpy(h.data() + 296 + 88, idd, 72);
    std::memcpy(h.data() + 296 + 160, idd, 72);
    put<double>(h, 296 + 256, 1.0);
    for (int a = 0; a < 3; ++a) {
        put<double>(h, 560 + 8 * a, double(bmin[a]) - 0.5);
        put<double>(h, 584 + 8 * a, double(bmax[a]) + 0.5);
        put<double>(h, 608 + 8 * a, 1.0);
    }
    put<uint32_t>(h, 632, 2u);                                  // fog volume
    put<uint32_t>(h, 636, 1u);                                  // float
    const uint64_t t = kGrid;
    put<uint64_t>(h, t + 0, L.leaf0 - t);
    put<uint64_t>(h, t + 8, L.lower0 - t);
    put<uint64_t>(h, t + 16, L.upper - t);
    put<uint64_t>(h, t + 24, L.root - t);
    put<uint32_t>(h, t + 32, uint32_t(n));
    put<uint32_t>(h, t + 36, uint32_t(L.lowers));
    put<uint32_t>(h, t + 40, 1u);
    put<uint64_t>(h, t + 56, n * 512);
    for (int a = 0; a < 3; ++a) {
        put<int32_t>(h, L.root + 4 * a, bmin[a]);
        put<int32_t>(h, L.root + 12 + 4 * a, bmax[a]);
    }
    put<uint32_t>(h, L.root + 24, 1u);                          // one tile
    put<float>(h, L.root + 28, 0.f);                            // background
    put<float>(h, L.root + 32, 0.5f);
    put<float>(h, L.root + 36, 1.5f);
    const uint64_t tile = L.root + kRoot;
    put<uint64_t>(h, tile + 0, 0);                              // key of (0, 0, 0)
    put<int64_t>(h, tile + 8, int64_t(L.upper - L.root));
    put<uint32_t>(h, tile + 16, 1u);                            // active
    out.write(reinterpret_cast<const char *>(h.data()), std::streamsize(h.size()));

    // Upper node
    std::vector<uint8_t> u(kUpper, 0);
    for (int a = 0; a < 3; ++a) { put<int32_t>(u, 4 * a, bmin[a]); put<int32_t>(u, 12 + 4 * a, bmax[a]); }
    for (uint64_t l = 0; l < L.lowers; ++l) {
        u[4128 + l / 8] |= uint8_t(1u << (l % 8));             // child mask
        put<int64_t>(u, 8256 + 8 * l, int64_t(L.lower0 + l * kLower - L.upper));
    }
    put<float>(u, 8224, 0.5f);
    put<float>(u, 8228, 1.5f);
    out.write(reinterpret_cast<const char *>(u.data()), std::streamsize(u.size()));

    // Lower nodes
    std::vector<uint8_t> lw(kLower);
    for (uint64_t l = 0; l < L.lowers; ++l) {
        std::fill(lw.begin(), lw.end(), 0);
        int32_t o[3];
        Layout::lower_origin(l, o);
        const uint64_t count = std::min<uint64_t>(4096, n - l * 4096);
        for (int a = 0; a < 3; ++a) { put<int32_t>(lw, 4 * a, o[a]); put<int32_t>(lw, 12 + 4 * a, o[a] + 127); }
        const uint64_t node = L.lower0 + l * kLower;
        for (uint64_t e = 0; e < count; ++e) {
            lw[544 + e / 8] |= uint8_t(1u << (e % 8));
            put<int64_t>(lw, 1088 + 8 * e, int64_t(L.leaf0 + (l * 4096 + e) * kLeaf - node));
        }
        put<float>(lw, 1056, 0.5f);
        put<float>(lw, 1060, 1.5f);
        out.write(reinterpret_cast<const char *>(lw.data()), std::streamsize(lw.size()));
    }

    // Leaves, in batches of 4096
    std::vector<uint8_t> batch(4096 * kLeaf);
    for (uint64_t first = 0; first < n; first += 4096) {
        const uint64_t count = std::min<uint64_t>(4096, n - first);
        for (uint64_t m = 0; m < count; ++m) {
            uint8_t *p = batch.data() + m * kLeaf;
            std::memset(p, 0, kLeaf);
            int32_t o[3];
            Layout::leaf_origin(first + m, o);
            std::memcpy(p, o, 12);
            p[12] = p[13] = p[14] = 7;                          // bbox dif
            p[15] = 2;                                          // flags: bbox is valid
            std::memset(p + 16, 0xff, 64);                      // all active
            float vmin = 2.f, vmax = 0.f;
            for (int i = 0; i < 8; ++i)
                for (int j = 0; j < 8; ++j)
                    for (int k = 0; k < 8; ++k) {
                        const float v = value_at(o[0] + i, o[1] + j, o[2] + k);
                        std::memcpy(p + 96 + 4 * ((i << 6) | (j << 3) | k), &v, 4);
                        vmin = std::min(vmin, v);
                        vmax = std::max(vmax, v);
                    }
            std::memcpy(p + 80, &vmin, 4);
            std::memcpy(p + 84, &vmax, 4);
        }
        out.write(reinterpret_cast<const char *>(batch.data()), std::streamsize(count * kLeaf));
    }
    out.close();
    if (!out) { std::fprintf(stderr, "nvdb_big_grid: error writing %s\n", path.c_str()); return 1; }

    // First leaf whose values lie past 4 GiB
    const uint64_t four = uint64_t(1) << 32;
    std::printf("size %llu leaves %llu lowers %llu bbox %d %d %d %d %d %d\n",
                (unsigned long long) L.size, (unsigned long long) n,
                (unsigned long long) L.lowers, bmin[0], bmin[1], bmin[2], bmax[0], bmax[1], bmax[2]);
    if (L.size > four) {
        const uint64_t m = (four - L.leaf0 + kLeaf - 1) / kLeaf;
        int32_t o[3];
        Layout::leaf_origin(m, o);
        std::printf("past4g_leaf %llu origin %d %d %d\n", (unsigned long long) m, o[0], o[1], o[2]);
    }
    return 0;
}

int probe(const std::string &path, int argc, char **argv) {
    const int fd = open(path.c_str(), O_RDONLY);
    struct stat st;
    if (fd < 0 || fstat(fd, &st) != 0) { std::perror(path.c_str()); return 1; }
    void *p = mmap(nullptr, size_t(st.st_size), PROT_READ, MAP_PRIVATE, fd, 0);
    if (p == MAP_FAILED) { std::perror("mmap"); return 1; }
    pnanovdb_buf_t buf;
    buf.data = static_cast<uint32_t *>(p);
    pnanovdb_grid_handle_t grid = { pnanovdb_address_null() };
    pnanovdb_root_handle_t root = pnanovdb_tree_get_root(buf, pnanovdb_grid_get_tree(buf, grid));
    for (int a = 0; a + 2 < argc; a += 3) {
        pnanovdb_coord_t ijk = { std::atoi(argv[a]), std::atoi(argv[a + 1]), std::atoi(argv[a + 2]) };
        pnanovdb_uint32_t level = 0;
        pnanovdb_address_t addr = pnanovdb_root_get_value_address_and_level(
            PNANOVDB_GRID_TYPE_FLOAT, buf, root, &ijk, &level);
        const float v = pnanovdb_read_float(buf, addr);
        std::printf("%d %d %d %u %llu %.9g\n", ijk.x, ijk.y, ijk.z, level,
                    (unsigned long long) addr.byte_offset, double(v));
    }
    munmap(p, size_t(st.st_size));
    close(fd);
    return 0;
}

int check(const std::string &path) {
    std::ifstream in(path, std::ios::binary);
    std::vector<char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    void *mem = std::aligned_alloc(32, (bytes.size() + 31) / 32 * 32);
    std::memcpy(mem, bytes.data(), bytes.size());
    const auto *grid = reinterpret_cast<const nanovdb::NanoGrid<float> *>(mem);
    int bad = 0;
    if (!grid->isValid() || grid->gridType() != nanovdb::GridType::Float) {
        std::fprintf(stderr, "not a valid NanoVDB float grid\n");
        return 1;
    }
    if (!nanovdb::isValid(*grid, /*detailed=*/true, /*verbose=*/true)) {
        std::fprintf(stderr, "nanovdb::isValid(detailed) fails\n");
        bad++;
    }
    auto acc = grid->getAccessor();
    const auto bbox = grid->indexBBox();
    uint64_t count = 0;
    for (int32_t x = bbox.min()[0]; x <= bbox.max()[0]; ++x)
    for (int32_t y = bbox.min()[1]; y <= bbox.max()[1]; ++y)
    for (int32_t z = bbox.min()[2]; z <= bbox.max()[2]; ++z) {
        const nanovdb::Coord c(x, y, z);
        const float want = value_at(c[0], c[1], c[2]);
        float got = acc.getValue(c);
        // Voxels of the bbox outside every leaf read the background (0)
        if (got != want && got != 0.f) { if (bad++ < 5) std::fprintf(stderr, "value differs at %d %d %d\n", c[0], c[1], c[2]); }
        count += got == want;
    }
    const uint64_t active = grid->activeVoxelCount();
    std::printf("voxels %llu matching, active %llu, leaves %u\n", (unsigned long long) count,
                (unsigned long long) active, grid->tree().nodeCount(0));
    std::free(mem);
    return bad == 0 && count == active ? 0 : 1;
}

} // namespace

int main(int argc, char **argv) {
    const std::string cmd = argc > 1 ? argv[1] : "";
    if (cmd == "write" && argc == 4)
        return write_grid(argv[2], std::strtoull(argv[3], nullptr, 10));
    if (cmd == "probe" && argc >= 3)
        return probe(argv[2], argc - 3, argv + 3);
    if (cmd == "check" && argc == 3)
        return check(argv[2]);
    std::fprintf(stderr, "usage: nvdb_big_grid write OUT.nvdb LEAVES | probe FILE i j k ... | check FILE\n");
    return 2;
}
