// Typed test volumes (see typed_grids.h).

#include "typed_grids.h"

#include <nanovdb/util/OpenToNanoVDB.h>

#include <immintrin.h>

#include <cstring>
#include <stdexcept>

namespace nvdb_test {

const std::vector<std::string> &type_names() {
    static const std::vector<std::string> names = { "float", "fp4", "fp8", "fp16", "fpn", "half",
                                                    "vec3f" };
    return names;
}

uint32_t grid_type_of(const std::string &type) {
    if (type == "float") return 1;
    if (type == "half") return 9;
    if (type == "fp4") return 13;
    if (type == "fp8") return 14;
    if (type == "fp16") return 15;
    if (type == "fpn") return 16;
    if (type == "vec3f") return 6;
    throw std::invalid_argument("unknown value type \"" + type +
                                "\"; valid: float, fp4, fp8, fp16, fpn, half, vec3f");
}

std::array<float, 3> vec3_of(float v) { return { v, v * 0.5f + 0.1f, v * v }; }

uint16_t f16c_from_float(float f) {
    return uint16_t(_cvtss_sh(f, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC));
}

float f16c_to_float(uint16_t h) { return _cvtsh_ss(h); }

namespace {

template <typename T> T get(const uint8_t *p) {
    T v;
    std::memcpy(&v, p, sizeof(T));
    return v;
}
template <typename T> void put(uint8_t *p, T v) { std::memcpy(p, &v, sizeof(T)); }

/// Writes a float at `from` as a half at `to`, zeroing `width` bytes first
void put_half(uint8_t *to, float f, size_t width) {
    std::memset(to, 0, width);
    put<uint16_t>(to, f16c_from_float(f));
}

} // namespace

std::vector<uint32_t> to_half(const nanovdb::NanoGrid<float> &grid, uint64_t &bytes) {
    // Offsets of PNanoVDB 32.4's float and Half rows (they share the tree
    // layout but the leaves: 2144 bytes of floats -> 1120 bytes of halves)
    constexpr uint64_t GRID = 672, ROOT_SIZE = 64, TILE = 32, TILE_VALUE = 20,
                       UPPER_TABLE = 8256, UPPER_SIZE = 270400, LOWER_TABLE = 1088,
                       LOWER_SIZE = 33856, FLOAT_LEAF = 2144, HALF_LEAF = 1120, LEAF_TABLE = 96;
    const uint8_t *src = reinterpret_cast<const uint8_t *>(&grid);
    const uint8_t *tree = src + GRID;
    const uint64_t leaf_off = get<uint64_t>(tree + 0), lower_off = get<uint64_t>(tree + 8),
                   upper_off = get<uint64_t>(tree + 16), root_off = get<uint64_t>(tree + 24);
    const uint32_t leaves = get<uint32_t>(tree + 32), lowers = get<uint32_t>(tree + 36),
                   uppers = get<uint32_t>(tree + 40);
    const uint64_t old_size = get<uint64_t>(src + 32);
    const uint64_t leaf_begin = GRID + leaf_off;
    if (leaves && leaf_begin + uint64_t(leaves) * FLOAT_LEAF != old_size)
        throw std::runtime_error("to_half: the leaves are not the last part of the grid");
    bytes = leaves ? leaf_begin + uint64_t(leaves) * HALF_LEAF : old_size;

    std::vector<uint32_t> words((bytes + 3) / 4, 0u);
    uint8_t *dst = reinterpret_cast<uint8_t *>(words.data());
    std::memcpy(dst, src, leaves ? leaf_begin : old_size);
    put<uint64_t>(dst + 32, bytes);        // GridData.mGridSize
    put<uint32_t>(dst + 636, 9u);          // GridData.mGridType = Half
    put<uint64_t>(dst + 8, 0u);            // checksum: no longer valid

    // Root: background (28) and the stats (32..47) as halves; tile values
    const uint64_t root = GRID + root_off;
    const float background = get<float>(src + root + 28);
    std::memset(dst + root + 28, 0, ROOT_SIZE - 28);
    put<uint16_t>(dst + root + 28, f16c_from_float(background));
    const uint32_t tiles = get<uint32_t>(src + root + 24);
    for (uint32_t t = 0; t < tiles; ++t) {
        const uint64_t tile = root + ROOT_SIZE + uint64_t(t) * TILE;
        put_half(dst + tile + TILE_VALUE, get<float>(src + tile + TILE_VALUE), 4);
    }
    // Internal nodes: tile values become halves (entries stay 8 bytes); the
    // lower nodes' child offsets follow the leaves' new positions; the
    // node statistics are cleared (no reader uses them)
    auto internal = [&](uint64_t begin, uint32_t count, uint64_t size, uint64_t table,
                        uint32_t entries, uint64_t mask_off, bool lower) {
        for (uint32_t n = 0; n < count; ++n) {
            const uint64_t node = begin + uint64_t(n) * size;
            std::memset(dst + node + mask_off + entries / 8, 0, table - mask_off - entries / 8);
            for (uint32_t e = 0; e < entries; ++e) {
                const uint64_t at = node + table + uint64_t(e) * 8;
                const bool child = (get<uint32_t>(src + node + mask_off + 4 * (e >> 5)) >> (e & 31)) & 1u;
                if (!child) {
                    put_half(dst + at, get<float>(src + at), 8);
                } else if (lower) {
                    const uint64_t target = uint64_t(int64_t(node) + get<int64_t>(src + at));
                    const uint64_t index = (target - leaf_begin) / FLOAT_LEAF;
                    put<int64_t>(dst + at, int64_t(leaf_begin + index * HALF_LEAF) - int64_t(node));
                }
            }
        }
    };
    // the child mask follows the value mask (both entries/8 bytes): stats
    // start after the child mask
    internal(GRID + upper_off, uppers, UPPER_SIZE, UPPER_TABLE, 32768, 32 + 4096, false);
    internal(GRID + lower_off, lowers, LOWER_SIZE, LOWER_TABLE, 4096, 32 + 512, true);
    for (uint32_t n = 0; n < leaves; ++n) {
        const uint8_t *from = src + leaf_begin + uint64_t(n) * FLOAT_LEAF;
        uint8_t *to = dst + leaf_begin + uint64_t(n) * HALF_LEAF;
        std::memcpy(to, from, 80); // bbox, flags, value mask
        for (uint32_t v = 0; v < 512; ++v)
            put<uint16_t>(to + LEAF_TABLE + 2 * v, f16c_from_float(get<float>(from + LEAF_TABLE + 4 * v)));
    }
    (void) lower_off;
    return words;
}

namespace {

template <typename BuildT>
nanovdb::GridHandle<nanovdb::HostBuffer> convert(const openvdb::FloatGrid &grid) {
    return nanovdb::openToNanoVDB<nanovdb::HostBuffer, openvdb::FloatTree, BuildT>(grid);
}

} // namespace

TypedGrid make_typed_grid(const std::string &name, const std::string &type, int scale) {
    TypedGrid g;
    g.name = name;
    g.type = type;
    g.grid_type = grid_type_of(type);
    openvdb::FloatGrid::Ptr vdb = make_vdb_grid(name, scale);
    if (type == "fpn" && vdb->tree().leafCount() == 0) // it indexes the leaf array regardless
        throw std::invalid_argument("grid \"" + name + "\" has no leaves: NanoVDB 32.4's FpN "
                                    "encoder crashes on it (vdb2nvdb writes Fp16 instead)");
    g.float_grid = nanovdb::openToNanoVDB(*vdb);
    if (type == "half") {
        g.words = to_half(*g.float_grid.grid<float>(), g.bytes);
        return g;
    }
    if (type == "vec3f") {
        auto vec = openvdb::Vec3SGrid::create(openvdb::Vec3s(vec3_of(vdb->background()).data()));
        vec->setTransform(vdb->transform().copy());
        vec->setName(vdb->getName());
        auto &tree = vec->tree();
        for (auto it = vdb->cbeginValueAll(); it; ++it) { // voxels and tiles, on and off
            const std::array<float, 3> c = vec3_of(*it);
            const openvdb::Vec3s v(c[0], c[1], c[2]);
            if (it.isVoxelValue()) {
                tree.setValue(it.getCoord(), v);
                if (!it.isValueOn())
                    tree.setValueOff(it.getCoord());
            } else {
                tree.addTile(it.getLevel(), it.getCoord(), v, it.isValueOn());
            }
        }
        g.handle = nanovdb::openToNanoVDB(*vec);
    } else if (type == "float") g.handle = nanovdb::openToNanoVDB(*vdb);
    else if (type == "fp4") g.handle = convert<nanovdb::Fp4>(*vdb);
    else if (type == "fp8") g.handle = convert<nanovdb::Fp8>(*vdb);
    else if (type == "fp16") g.handle = convert<nanovdb::Fp16>(*vdb);
    else g.handle = convert<nanovdb::FpN>(*vdb);
    g.bytes = g.handle.size();
    g.words.assign((g.bytes + 3) / 4, 0u);
    std::memcpy(g.words.data(), g.handle.data(), g.bytes);
    return g;
}

bool has_typed_grid(const std::string &name, const std::string &type) {
    return type != "fpn" || make_vdb_grid(name)->tree().leafCount() != 0;
}

std::function<void(const nanovdb::Coord &, float *)> TypedGrid::reference3() const {
    auto acc = handle.grid<nanovdb::Vec3f>()->getAccessor();
    return [acc](const nanovdb::Coord &ijk, float *out) mutable {
        const nanovdb::Vec3f v = acc.getValue(ijk);
        out[0] = v[0]; out[1] = v[1]; out[2] = v[2];
    };
}

std::function<float(const nanovdb::Coord &)> TypedGrid::reference() const {
    auto with = [this](auto *grid) -> std::function<float(const nanovdb::Coord &)> {
        auto acc = grid->getAccessor();
        return [acc](const nanovdb::Coord &ijk) mutable { return float(acc.getValue(ijk)); };
    };
    switch (grid_type) {
        case 1: return with(handle.grid<float>());
        case 13: return with(handle.grid<nanovdb::Fp4>());
        case 14: return with(handle.grid<nanovdb::Fp8>());
        case 15: return with(handle.grid<nanovdb::Fp16>());
        case 16: return with(handle.grid<nanovdb::FpN>());
        default: {
            auto acc = float_grid.grid<float>()->getAccessor();
            return [acc](const nanovdb::Coord &ijk) mutable {
                return f16c_to_float(f16c_from_float(acc.getValue(ijk)));
            };
        }
    }
}

} // namespace nvdb_test
