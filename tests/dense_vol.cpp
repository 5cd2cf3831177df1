// Dense exports of the test grids as Mitsuba .vol files. See grids.h.

#include "grids.h"

#include <cstring>
#include <fstream>
#include <functional>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace nvdb_test {

uint64_t dense_voxel_count(const nanovdb::NanoGrid<float> &grid) {
    const nanovdb::CoordBBox bbox = grid.indexBBox();
    unsigned __int128 count = 1; // up to (2^32)^3: 96 bits
    for (int a = 0; a < 3; ++a) {
        if (bbox.min()[a] > bbox.max()[a])
            return 1; // empty grid: one background voxel
        count *= uint64_t(int64_t(bbox.max()[a]) - int64_t(bbox.min()[a]) + 1);
    }
    const uint64_t max = std::numeric_limits<uint64_t>::max();
    return count > max ? max : uint64_t(count); // saturates; far past any limit anyway
}

void write_dense_vol(const nanovdb::NanoGrid<float> &grid, const std::string &path,
                     const std::function<float(const nanovdb::Coord &)> &value) {
    write_dense_vol(grid, path, 1, [&](const nanovdb::Coord &ijk, float *out) {
        out[0] = value ? value(ijk) : grid.getAccessor().getValue(ijk);
    });
}

void write_dense_vol(const nanovdb::NanoGrid<float> &grid, const std::string &path,
                     int channels,
                     const std::function<void(const nanovdb::Coord &, float *)> &values) {
    const uint64_t count = dense_voxel_count(grid);
    if (count > max_dense_voxels) {
        std::ostringstream msg;
        const nanovdb::CoordBBox bbox = grid.indexBBox();
        msg << "write_dense_vol(\"" << path << "\"): grid \"" << grid.gridName()
            << "\" has the index bbox [" << bbox.min()[0] << ", " << bbox.min()[1] << ", "
            << bbox.min()[2] << "] .. [" << bbox.max()[0] << ", " << bbox.max()[1] << ", "
            << bbox.max()[2] << "], " << count
            << " voxels dense; the limit is " << max_dense_voxels;
        throw std::length_error(msg.str());
    }

    const nanovdb::CoordBBox bbox = grid.indexBBox();
    const bool empty = bbox.min()[0] > bbox.max()[0] || bbox.min()[1] > bbox.max()[1] ||
                       bbox.min()[2] > bbox.max()[2];
    int32_t res[3], min[3];
    for (int a = 0; a < 3; ++a) {
        min[a] = empty ? 0 : bbox.min()[a];
        res[a] = empty ? 1 : int32_t(int64_t(bbox.max()[a]) - int64_t(bbox.min()[a]) + 1);
    }

    // Little-endian serialisation, whatever the host's byte order.
    std::vector<unsigned char> bytes;
    auto put_u32 = [&bytes](uint32_t v) {
        for (int b = 0; b < 4; ++b)
            bytes.push_back(static_cast<unsigned char>(v >> (8 * b)));
    };
    auto put_i32 = [&](int32_t v) { put_u32(static_cast<uint32_t>(v)); };
    auto put_f32 = [&](float v) {
        uint32_t bits;
        std::memcpy(&bits, &v, sizeof(bits));
        put_u32(bits);
    };

    std::ofstream file(path, std::ios::binary);
    if (!file)
        throw std::runtime_error("write_dense_vol: cannot open \"" + path + "\" for writing");
    bytes.insert(bytes.end(), { 'V', 'O', 'L', 3 });
    put_i32(1); // encoding: float32
    put_i32(res[0]);
    put_i32(res[1]);
    put_i32(res[2]);
    put_i32(channels);
    for (int a = 0; a < 3; ++a) // bbox min: the index bbox [min, max + 1]
        put_f32(float(min[a]));
    for (int a = 0; a < 3; ++a)
        put_f32(float(int64_t(min[a]) + res[a]));

    for (int32_t z = 0; z < res[2]; ++z) {
        for (int32_t y = 0; y < res[1]; ++y)
            for (int32_t x = 0; x < res[0]; ++x) {
                // an empty grid: its background, read at the origin
                const nanovdb::Coord ijk = empty ? nanovdb::Coord(0, 0, 0)
                                                 : nanovdb::Coord(min[0] + x, min[1] + y, min[2] + z);
                float v[3] = { 0.f, 0.f, 0.f };
                values(ijk, v);
                for (int c = 0; c < channels; ++c)
                    put_f32(v[c]);
            }
        file.write(reinterpret_cast<const char *>(bytes.data()), std::streamsize(bytes.size()));
        bytes.clear();
    }
    if (!file.flush())
        throw std::runtime_error("write_dense_vol: error writing \"" + path + "\"");
}

} // namespace nvdb_test
