// The dense .vol export. See dense.h.

#include "dense.h"

#include <cerrno>
#include <cstring>
#include <fstream>
#include <type_traits>
#include <vector>

#include <unistd.h>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <nanovdb_convert/format.h>

namespace vdb2nvdb {

using openvdb::CoordBBox;

DenseBox dense_box(const CoordBBox &b) {
    DenseBox d;
    if (!b.empty()) {
        d.min = b.min();
        d.max = b.max();
    }
    return d;
}

uint64_t dense_limit(const Options &opts) {
    if (opts.max_dense_bytes)
        return opts.max_dense_bytes;
    uint64_t mem = physical_memory();
    return mem ? mem / 2 : (uint64_t(4) << 30);
}

uint64_t physical_memory() {
    long pages = sysconf(_SC_PHYS_PAGES), size = sysconf(_SC_PAGE_SIZE);
    return (pages > 0 && size > 0) ? uint64_t(pages) * uint64_t(size) : 0;
}

namespace {

template <typename BuildT>
void write_dense_grid(const nanovdb::NanoGrid<BuildT> &nano,
                      const openvdb::math::Transform &xform, const DenseBox &box,
                      const std::string &path) {
    const int32_t res[3] = { box.max.x() - box.min.x() + 1, box.max.y() - box.min.y() + 1,
                             box.max.z() - box.min.z() + 1 };
    // World-space extent of the voxels' cells: the index box [min - 0.5,
    // max + 0.5] through the grid transform (its axis-aligned bounds)
    openvdb::math::BBox<openvdb::Vec3d> wb;
    for (int c = 0; c < 8; ++c) {
        openvdb::Vec3d p((c & 1) ? box.max.x() + 0.5 : box.min.x() - 0.5,
                         (c & 2) ? box.max.y() + 0.5 : box.min.y() - 0.5,
                         (c & 4) ? box.max.z() + 0.5 : box.min.z() - 0.5);
        wb.expand(xform.indexToWorld(p));
    }
    std::ofstream os(path, std::ios::binary | std::ios::trunc);
    if (!os)
        throw Error("cannot write " + dq(path) + ": " + std::strerror(errno));
    using Value = typename nanovdb::NanoGrid<BuildT>::ValueType;
    constexpr int channels = std::is_same_v<Value, nanovdb::Vec3f> ? 3 : 1;
    const char magic[4] = { 'V', 'O', 'L', 3 };
    const int32_t header[5] = { 1, res[0], res[1], res[2], channels };
    const float bbox[6] = { float(wb.min()[0]), float(wb.min()[1]), float(wb.min()[2]),
                            float(wb.max()[0]), float(wb.max()[1]), float(wb.max()[2]) };
    os.write(magic, 4);
    os.write(reinterpret_cast<const char *>(header), sizeof(header));
    os.write(reinterpret_cast<const char *>(bbox), sizeof(bbox));
    // One z slab at a time: memory is one slab, not the dense grid
    std::vector<float> slab(size_t(res[0]) * size_t(res[1]) * channels);
    for (int32_t z = 0; z < res[2] && os; ++z) {
        tbb::parallel_for(tbb::blocked_range<int32_t>(0, res[1], 16),
                          [&](const tbb::blocked_range<int32_t> &r) {
            auto acc = nano.getAccessor();
            for (int32_t y = r.begin(); y != r.end(); ++y)
                for (int32_t x = 0; x < res[0]; ++x) {
                    const Value v = acc.getValue(
                        nanovdb::Coord(box.min.x() + x, box.min.y() + y, box.min.z() + z));
                    float *out = &slab[(size_t(y) * size_t(res[0]) + size_t(x)) * channels];
                    if constexpr (channels == 3) {
                        out[0] = v[0]; out[1] = v[1]; out[2] = v[2];
                    } else {
                        out[0] = v;
                    }
                }
        });
        os.write(reinterpret_cast<const char *>(slab.data()),
                 std::streamsize(slab.size() * sizeof(float)));
    }
    os.close();
    if (os.fail())
        throw Error("error writing " + dq(path) + " (disk full?)");
}

} // namespace

void write_dense(const Handle &nano, const std::string &name,
                 const openvdb::math::Transform &xform, const DenseBox &box,
                 const std::string &path) {
    if (auto *g = nano.grid<nanovdb::Vec3f>())
        write_dense_grid(*g, xform, box, path);
    else
        with_grid(nano, name, [&](const auto &grid) { write_dense_grid(grid, xform, box, path); });
}

} // namespace vdb2nvdb
