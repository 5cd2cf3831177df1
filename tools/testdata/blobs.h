// Unions of spheres ("blobs"): the shapes of the test clouds before their
// noise (test_grids.h: noisy_cloud; generate_cases.h: cloud, cloudfield).
#pragma once

#include <algorithm>
#include <cmath>

namespace nvdb_testdata {

struct Blob { double x, y, z, r; };

/// max over the blobs of 1 - |p - centre| / radius: 1 at a blob's centre, 0
/// on its surface, negative outside every blob. `blobs`: any range of Blob.
template <typename Blobs> double blob_shape(double x, double y, double z, const Blobs &blobs) {
    double shape = -1e30;
    for (const Blob &b : blobs) {
        const double d = std::sqrt((x - b.x) * (x - b.x) + (y - b.y) * (y - b.y) +
                                   (z - b.z) * (z - b.z));
        shape = std::max(shape, 1.0 - d / b.r);
    }
    return shape;
}

} // namespace nvdb_testdata
